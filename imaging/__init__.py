"""Acoustic imaging with a calibrated array (paper section VI).

Cross-spectral matrices (`csm`), steering vectors (`steering`), delay-and-sum beamforming
(`beamform`) and CLEAN-SC (`cleansc`) over scan surfaces (`grid`), sub-grid peaks (`peaks`),
maps drawn on camera images (`overlay`) and the localization evaluation of a session
(`evaluate`). The geometry (microphones, speed of sound, cameras, rig poses) comes from a
calibration result or a simulation's truth (`geometry`).
"""

from .beamform import beamform, beamform_csm
from .cleansc import (
    CleanScOptions,
    CleanScResult,
    Component,
    StopRule,
    clean_sc,
    clean_sc_many,
    clean_sc_spectra,
)
from .csm import (
    CrossSpectra,
    WelchOptions,
    band_bins,
    band_edges,
    cross_spectra,
    octave_band_centres,
    remove_diagonal,
)
from .geometry import ArrayGeometry, BoardPose, CameraView, geometry_from_dict, load_geometry
from .grid import PlaneGrid
from .peaks import quadratic_offset, subgrid_peak
from .steering import Formulation, SteeringModel

__all__ = [
    "ArrayGeometry", "BoardPose", "CameraView", "CleanScOptions", "CleanScResult", "Component",
    "CrossSpectra", "Formulation", "PlaneGrid", "SteeringModel", "StopRule", "WelchOptions",
    "band_bins", "band_edges", "beamform", "beamform_csm", "clean_sc", "clean_sc_many",
    "clean_sc_spectra",
    "cross_spectra", "geometry_from_dict", "load_geometry", "octave_band_centres",
    "quadratic_offset", "remove_diagonal", "subgrid_peak",
]
