"""Tactile perception: warp, calibration, depth reconstruction, markers.

Pixel frames: images are ``[row, col]`` with ``x`` the column (right) and ``y``
the row (down); depth is metres, positive into the gel.
"""

from estimator.perception.calibration import Calibration, load_calibration
from estimator.perception.calibration_fit import fit_calibration
from estimator.perception.depth import SphereFit, fit_sphere, poisson_depth, reconstruct_depth
from estimator.perception.markers import detect_markers, inpaint_markers
from estimator.perception.press_circles import PressRings, detect_press_circle, press_rings
from estimator.perception.presses import PressSet, load_presses, split_presses
from estimator.perception.warp import warp_and_crop, warp_maps, warp_matrix, warp_points

__all__ = [
    "Calibration",
    "PressRings",
    "PressSet",
    "SphereFit",
    "detect_markers",
    "detect_press_circle",
    "fit_calibration",
    "fit_sphere",
    "inpaint_markers",
    "load_calibration",
    "load_presses",
    "poisson_depth",
    "press_rings",
    "reconstruct_depth",
    "split_presses",
    "warp_and_crop",
    "warp_maps",
    "warp_matrix",
    "warp_points",
]
