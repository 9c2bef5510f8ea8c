"""Scan configurations the hardware cannot do are refused with errors that say why."""

from typing import Any

import pytest

from daq import (
    BOARD_MODELS,
    ConfigurationError,
    InputChannel,
    OutputChannel,
    ScanConfig,
    board_model,
    codes_to_volts,
    volts_to_codes,
)


def _cfg(**kw: Any) -> ScanConfig:
    base: dict[str, Any] = {"inputs": (InputChannel(channel=0),), "sample_rate_hz": 96_000.0}
    base.update(kw)
    return ScanConfig(**base)


def test_catalogue_has_the_paper_boards() -> None:
    assert board_model("DT9836-12-2").n_inputs == 12
    assert board_model("DT9836-12-2").n_outputs == 2
    assert board_model("DT9816-A").n_outputs == 0
    assert board_model("DT9816-A").max_input_rate_hz >= 96_000
    assert board_model("DT9816").max_input_rate_hz < 96_000
    assert {"DT9836-12-0", "DT9836-6-2", "DT9836-6-0", "DT9836-6-4"} <= set(BOARD_MODELS)


def test_unknown_model_lists_known_ones() -> None:
    with pytest.raises(ConfigurationError, match="DT9836-12-2"):
        board_model("DT9999")


def test_valid_config_passes() -> None:
    cfg = _cfg(inputs=tuple(InputChannel(channel=c) for c in range(12)),
               outputs=(OutputChannel(channel=1),))
    cfg.check_against(board_model("DT9836-12-2"), "S1")


@pytest.mark.parametrize(
    ("model", "cfg", "message"),
    [
        ("DT9816", _cfg(), "above the board's maximum"),
        ("DT9836-6-2", _cfg(inputs=(InputChannel(channel=6),)), "input channel 6 does not exist"),
        ("DT9816-A", _cfg(outputs=(OutputChannel(channel=0),)), "no analog outputs"),
        ("DT9836-12-2", _cfg(outputs=(OutputChannel(channel=2),)), "output channel 2 does not"),
        ("DT9836-12-2", _cfg(inputs=(InputChannel(channel=0, range_v=5.0),)), "not offered"),
    ],
)
def test_impossible_configs_are_refused(model: str, cfg: ScanConfig, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message) as info:
        cfg.check_against(board_model(model), "SER42")
    assert "SER42" in str(info.value) and model in str(info.value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"inputs": ()},
        {"inputs": (InputChannel(channel=1), InputChannel(channel=1))},
        {"sample_rate_hz": 0.0},
        {"samples_per_channel": 0},
    ],
)
def test_malformed_configs_fail_validation(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        _cfg(**kwargs)


def test_codes_volts_round_trip_and_clipping() -> None:
    import numpy as np

    v = np.array([-10.0, -1.0, 0.0, 0.5, 9.99969482421875, 12.0])
    codes = volts_to_codes(v, 10.0)
    assert codes.dtype == np.int16
    assert codes[0] == -32768 and codes[-1] == 32767
    assert np.allclose(codes_to_volts(codes[1:5], 10.0), v[1:5], atol=10 / 32768)
