"""The simulated lab's air sensor: a thermometer, hygrometer and barometer beside the array."""

from __future__ import annotations

import numpy as np

from kernel.air import AirReading

from .world import World


class SimulatedAirSensor:
    """Reads the simulated world's air with the lab model's fixed calibration errors (drawn
    once per world, `LabTruth.sensor_errors`) and a little reading noise, stating the model's
    accuracy with every reading (`kernel.air.AirSensor`).

    The reading noise is seeded by the world's seed and the session's progress, so that a
    resumed capture reads what an uninterrupted one did.
    """

    def __init__(self, world: World) -> None:
        if world.lab.air_sensor is None:
            raise ValueError("the simulated lab has no air sensor (effect 'air-sensor')")
        self.world = world
        self.model = world.lab.air_sensor

    @property
    def name(self) -> str:
        return f"sim:{self.world.layout.name}:air"

    def read(self) -> AirReading:
        w, m = self.world, self.model
        errors = w.lab_truth.sensor_errors
        rng = np.random.default_rng([w.seed, 9, round(w.session_progress * 1_000_000)])
        return AirReading(
            temperature_c=round(w.air_temperature_c + errors[0]
                                + m.reading_noise_k * rng.standard_normal(), 4),
            temperature_std_k=m.temperature_std_k,
            relative_humidity=round(float(np.clip(w.relative_humidity + errors[1], 0, 1)), 4),
            relative_humidity_std=m.relative_humidity_std,
            pressure_pa=round(w.pressure_pa + errors[2], 1),
            pressure_std_pa=m.pressure_std_pa,
        )
