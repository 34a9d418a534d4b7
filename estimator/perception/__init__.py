"""Tactile perception: warp, calibration, depth reconstruction, markers.

Pixel frames: images are ``[row, col]`` with ``x`` the column (right) and ``y``
the row (down); depth is metres, positive into the gel.

The names below load their module on first use, so the live service, which reads
calibrations but never fits one, does not load the fitting and press-set code.
"""

from importlib import import_module
from typing import Any

_HOMES = {
    "Calibration": "calibration",
    "load_calibration": "calibration",
    "fit_calibration": "calibration_fit",
    "SphereFit": "depth",
    "fit_sphere": "depth",
    "poisson_depth": "depth",
    "reconstruct_depth": "depth",
    "detect_markers": "markers",
    "inpaint_markers": "markers",
    "PressRings": "press_circles",
    "detect_press_circle": "press_circles",
    "press_rings": "press_circles",
    "PressSet": "presses",
    "load_presses": "presses",
    "split_presses": "presses",
    "warp_and_crop": "warp",
    "warp_maps": "warp",
    "warp_matrix": "warp",
    "warp_points": "warp",
}

__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_HOMES[name]}"), name)
