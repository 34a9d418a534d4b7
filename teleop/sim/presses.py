"""Rigid-ball presses on a simulated sensor, in taxim's dataPack layout.

The estimator calibrates its colour-to-gradient map on presses of a ball of known
radius. :func:`simulate_presses` renders them on the simulated sensor so the estimator
can be calibrated for simulation exactly as for hardware (where taxim's recordings are
the reference). The file (:func:`write_presses`, ``np.savez_compressed``, no pickles) holds:

``f0``            uint8 (480, 640, 3): the no-contact raw frame (camera noise, JPEG).
``imgs``          uint8 (n, 480, 640, 3): raw frames of the presses (noise, JPEG).
``touch_center``  float64 (n, 2): press centres [x, y] in px of the WARPED-AND-CROPPED grid
                  (``sensor.image_shape``; a flat sensor's, ``model = "mini"``, is its raw frame).
``touch_radius``  int64 (n,): contact radius in grid px, rounded (as in taxim).
``names``         unicode (n + 1,): ``frame_0.jpg`` (f0), ``frame_1.jpg`` ... (the presses).
``img_size``      int64 (3,): raw frame shape.
``mm_per_px``     float64 0-d: gel surface per grid px.
``frame``         unicode 0-d: ``"warped_cropped"``: warp and crop the raw frames with the
                  sensor's settings before using the centres and radii.
``ball_radius_mm`` float64 0-d and ``press_depth_mm`` float64 (n,): the exact geometry
                  (contact radius = sqrt(2 R d - d^2)).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from teleop.errors import SimulationError
from teleop.progress import progress_bar
from teleop.sim.optics import OpticsRenderer
from teleop.staging import staged

__all__ = ["contact_radius_m", "simulate_presses", "sphere_press_height", "write_presses"]

# Keep every contact this many grid px away from the grid's edge.
EDGE_MARGIN_PX = 3.0


def contact_radius_m(ball_radius_m: float, depth_m: float) -> float:
    """Radius (m) of the circle where a rigid ball of ``ball_radius_m`` pressed ``depth_m`` meets the gel."""
    return float(np.sqrt(2.0 * ball_radius_m * depth_m - depth_m**2))


def sphere_press_height(shape: tuple[int, int], *, center_px: tuple[float, float],
                        ball_radius_m: float, depth_m: float, pixel_pitch_m: float) -> np.ndarray:
    """Gel indentation (m) of a rigid ball pressed into the gel: a spherical cap.

    h = max(0, d - (R - sqrt(R^2 - r^2))), r the distance from ``center_px`` = (x, y)
    in px of ``pixel_pitch_m``. Returns float64 of ``shape`` (rows, cols).
    """
    rows, cols = np.indices(shape, dtype=np.float64)
    r_sq = ((cols - center_px[0]) ** 2 + (rows - center_px[1]) ** 2) * pixel_pitch_m**2
    cap_drop = ball_radius_m - np.sqrt(np.maximum(ball_radius_m**2 - r_sq, 0.0))
    return np.where(r_sq < ball_radius_m**2, np.maximum(depth_m - cap_drop, 0.0), 0.0)


def _decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)


def simulate_presses(camera: OpticsRenderer, *, n: int, ball_radius_m: float,
                     depth_range_m: tuple[float, float], rng: np.random.Generator,
                     progress: bool = False) -> dict[str, np.ndarray]:
    """Press a rigid ball ``n`` times at random centres and depths; return the dataPack arrays.

    Parameters
    ----------
    camera : OpticsRenderer
        The simulated sensor's camera; frames are its captures (noise, JPEG), decoded.
    n : int
        Number of presses, >= 1.
    ball_radius_m : float
        Ball radius (m).
    depth_range_m : (float, float)
        Press depths (m) are drawn uniformly from [lo, hi]; 0 < lo <= hi <= ball
        radius and hi <= the gel's thickness.
    rng : numpy.random.Generator
        Draws centres and depths.
    progress : bool
        Show a tqdm bar on stderr.

    Returns
    -------
    dict of str to ndarray
        The keys and layout of the module docstring.
    """
    sensor = camera.sensor
    lo, hi = depth_range_m
    if n < 1:
        raise SimulationError(f"n = {n}: expected at least one press")
    if not 0.0 < lo <= hi <= ball_radius_m:
        raise SimulationError(
            f"depth range {lo * 1e3:g}..{hi * 1e3:g} mm: expected 0 < lo <= hi <= the ball radius "
            f"{ball_radius_m * 1e3:g} mm"
        )
    if hi > sensor.gel_thickness_m:
        raise SimulationError(
            f"depth range up to {hi * 1e3:g} mm: deeper than the gel ({sensor.gel_thickness_m * 1e3:g} mm)"
        )
    raw_shape = (sensor.raw_height_px, sensor.raw_width_px, 3)
    try:  # before any rendering: an absurd n fails at once, not after hours
        imgs = np.empty((n, *raw_shape), dtype=np.uint8)
    except (MemoryError, ValueError) as exc:  # ValueError: more bytes than numpy can index
        raise SimulationError(
            f"n = {n}: {n} presses of {raw_shape[1]}x{raw_shape[0]} px frames do not fit in memory"
        ) from exc
    rows, cols = sensor.image_shape
    pitch = sensor.pixel_pitch_m
    depths = rng.uniform(lo, hi, n)
    radii_px = np.array([contact_radius_m(ball_radius_m, d) for d in depths]) / pitch
    reach = radii_px + EDGE_MARGIN_PX
    if 2 * reach.max() >= min(rows, cols):
        raise SimulationError(
            f"a {2 * ball_radius_m * 1e3:g} mm ball pressed {hi * 1e3:g} mm does not fit on the "
            f"{cols}x{rows} px grid of sensor {sensor.finger!r}"
        )
    centres = np.column_stack([rng.uniform(reach, cols - 1 - reach), rng.uniform(reach, rows - 1 - reach)])

    f0 = _decode(camera.capture(np.zeros(sensor.image_shape)))
    for i in progress_bar(range(n), desc="presses", unit="press", enabled=progress):
        height = sphere_press_height(sensor.image_shape, center_px=tuple(centres[i]),
                                     ball_radius_m=ball_radius_m, depth_m=depths[i], pixel_pitch_m=pitch)
        imgs[i] = _decode(camera.capture(height))
    return {
        "f0": f0,
        "imgs": imgs,
        "touch_center": centres.astype(np.float64),
        "touch_radius": np.rint(radii_px).astype(np.int64),
        "names": np.array([f"frame_{i}.jpg" for i in range(n + 1)]),
        "img_size": np.array(f0.shape, dtype=np.int64),
        "mm_per_px": np.array(pitch * 1e3),
        "frame": np.array("warped_cropped"),
        "ball_radius_mm": np.array(ball_radius_m * 1e3),
        "press_depth_mm": depths * 1e3,
    }


def write_presses(path: str | Path, pack: dict[str, np.ndarray]) -> Path:
    """Write ``pack`` to exactly ``path`` as a compressed .npz (no pickled objects)."""
    path = Path(path)
    try:
        # Under a staged name, renamed over ``path`` once complete: an interrupted write leaves
        # the presses file there as it was.
        with staged(path) as partial, partial.open("wb") as stream:
            np.savez_compressed(stream, **pack)
    except OSError as exc:
        raise SimulationError(f"cannot write presses file {path}: {exc.strerror or exc}") from exc
    return path
