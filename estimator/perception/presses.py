"""Ball presses for calibration: reading them from files or folders, and splitting them.

A :class:`PressSet` holds a no-contact frame, the press images and their circles
(recorded, detected or none), and brings them into a sensor's pixel frame.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from estimator.errors import CalibrationError
from estimator.perception.calibration import _check_image, read_npz
from estimator.perception.press_circles import detect_press_circle
from estimator.perception.warp import warp_and_crop, warp_matrix, warp_points
from teleop.progress import progress_bar
from teleop.settings import SensorSettings

__all__ = ["PressSet", "load_presses", "split_presses"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
REFERENCE_NAME = re.compile(r"^(f0|ref|background)", re.IGNORECASE)


def split_presses(n_presses: int, train_fraction: float) -> np.ndarray:
    """Deterministic, evenly spread training indices (the rest are held out).

    ``round(train_fraction * n)`` indices (at least one), spread over the
    sequence so both halves cover the pad alike: 0.5 takes every other press.
    """
    if not (isinstance(n_presses, int) and n_presses >= 1):
        raise CalibrationError(f"n_presses: expected a positive integer, got {n_presses!r}")
    if not (isinstance(train_fraction, int | float) and 0.0 < train_fraction <= 1.0):
        raise CalibrationError(f"train_fraction: expected a value in (0, 1], got {train_fraction!r}")
    n_train = max(1, round(train_fraction * n_presses))
    return np.unique(np.arange(n_train) * n_presses // n_train)


@dataclass(frozen=True, eq=False)
class PressSet:
    """Ball presses ready for calibration, all in one pixel frame.

    Attributes
    ----------
    reference : ndarray
        uint8 BGR no-contact frame.
    images : ndarray
        uint8 (N, H, W, 3) presses.
    centers_px, radii_px : ndarray or None
        (N, 2) contact centres ``(x, y)`` and (N,) radii, pixels; None until
        known (a folder of images records none).
    circles : str
        ``"recorded"`` (annotations from the file), ``"detected"`` (found by
        :func:`detect_press_circle`) or ``"none"``.
    frame : str
        ``"raw"`` or ``"warped_cropped"``: the pixel frame of the circles (and
        of the images once :meth:`in_sensor_frame` has run).
    mm_per_px, ball_radius_mm : float or None
        Pixel pitch and ball radius stated by the file, if any.
    source : str
        Where it was read from.
    sha256 : str
        Fingerprint of the reference and images as read (before any warp).
    warped : bool
        Whether the images are in the sensor's warped-and-cropped frame.
    """

    reference: np.ndarray
    images: np.ndarray
    centers_px: np.ndarray | None
    radii_px: np.ndarray | None
    circles: str
    frame: str
    mm_per_px: float | None
    ball_radius_mm: float | None
    source: str
    sha256: str
    warped: bool = False

    def __len__(self) -> int:
        return len(self.images)

    def in_sensor_frame(self, sensor: SensorSettings, *, progress: bool = False) -> PressSet:
        """The same presses warped and cropped with ``sensor`` (circles mapped along).

        Raw-size images are warped; images already of ``sensor.image_shape``
        are kept only when the set says ``frame = "warped_cropped"``. Circles
        recorded in the raw frame are mapped through the warp, radii scaled by
        its local magnification (square root of the Jacobian determinant).
        A flat sensor (``model = "mini"``) has nothing to warp: its raw frame is
        its image (as the estimator reads it, :func:`~estimator.perception.grid.to_grid`),
        so raw-size presses and their circles are kept as they are.
        """
        raw_shape = (sensor.raw_height_px, sensor.raw_width_px)
        shape = self.reference.shape[:2]
        if shape == sensor.image_shape and (self.frame == "warped_cropped" or sensor.model == "mini"):
            return dataclasses.replace(self, frame="warped_cropped", warped=True)
        if shape != raw_shape:
            raise CalibrationError(
                f"{self.source}: images are {shape[0]} x {shape[1]}; sensor {sensor.finger!r} expects raw "
                f"{raw_shape[0]} x {raw_shape[1]} frames (or {sensor.image_shape} with frame = 'warped_cropped')"
            )
        images = np.stack([warp_and_crop(im, sensor) for im in progress_bar(
            self.images, desc="warping presses", unit="press", enabled=progress)])
        centers, radii = self.centers_px, self.radii_px
        if self.frame == "raw" and centers is not None:
            centers = warp_points(self.centers_px, sensor)
            scale = np.sqrt(np.abs(np.linalg.det(_warp_jacobian(warp_matrix(sensor), self.centers_px))))
            radii = self.radii_px * scale
        return dataclasses.replace(
            self, reference=warp_and_crop(self.reference, sensor), images=images,
            centers_px=centers, radii_px=radii, frame="warped_cropped", warped=True,
        )

    def with_detected_circles(self, *, max_radius_px: float | None = None, progress: bool = False) -> PressSet:
        """The same presses with circles found by :func:`detect_press_circle` in the images."""
        centers, radii = [], []
        for i, image in enumerate(progress_bar(self.images, desc="detecting press circles", unit="press",
                                       enabled=progress)):
            try:
                center, radius = detect_press_circle(image, self.reference, max_radius_px=max_radius_px)
            except CalibrationError as exc:
                raise CalibrationError(f"{self.source}: press {i}: {exc}") from exc
            centers.append(center)
            radii.append(radius)
        return dataclasses.replace(
            self, centers_px=np.array(centers), radii_px=np.array(radii), circles="detected",
            frame="warped_cropped" if self.warped else "raw",
        )


def _warp_jacobian(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2, 2) Jacobians of the homography at raw points (x, y)."""
    homogeneous = np.column_stack([points, np.ones(len(points))]) @ matrix.T
    w = homogeneous[:, 2:3]
    mapped = homogeneous[:, :2] / w
    # d(u_i)/d(x_j) = (M_ij - u_i * M_2j) / w
    return (matrix[None, :2, :2] - mapped[:, :, None] * matrix[None, 2:3, :2]) / w[:, :, None]


def _fingerprint(reference: np.ndarray, images: Sequence[np.ndarray]) -> str:
    digest = hashlib.sha256(reference.tobytes())
    for image in images:
        digest.update(image.tobytes())
    return digest.hexdigest()


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CalibrationError(f"{path}: not a readable image")
    return image


def load_presses(path: str | Path, *, progress: bool = False) -> PressSet:
    """Read ball presses from a taxim-style dataPack ``.npz`` or a folder of images.

    ``.npz`` members: ``f0`` (no-contact frame), ``imgs`` (N, H, W, 3) uint8,
    ``touch_center`` (N, 2) finite ``(x, y)`` px, ``touch_radius`` (N,) positive px; optional
    ``frame`` (``"raw"`` default, or ``"warped_cropped"``) and ``mm_per_px``.
    A folder holds one no-contact image named ``f0*``, ``ref*`` or
    ``background*`` and the press images (any other image file, sorted by
    name); it records no circles (see :meth:`PressSet.with_detected_circles`).
    Optional ``.npz`` members ``mm_per_px`` and ``ball_radius_mm`` are read
    into the set.

    Raises
    ------
    CalibrationError
        The path is missing or unreadable, a member or the reference image is
        missing, shapes and dtypes do not fit, a ``touch_center`` is not finite
        or a ``touch_radius`` not positive and finite; the message names the
        file and the member.
    """
    path = Path(path)
    if path.is_dir():
        return _load_folder(path, progress)
    members = read_npz(path, missing=f"presses {path} do not exist", kind="a press .npz (or a folder of images)")
    missing = sorted({"f0", "imgs", "touch_center", "touch_radius"} - set(members))
    if missing:
        raise CalibrationError(f"{path}: missing member(s) {', '.join(missing)} (a taxim-style dataPack needs f0, imgs, touch_center, touch_radius)")
    reference, images = members["f0"], members["imgs"]
    _check_image(f"{path}: f0", reference, None, CalibrationError)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[1:] != reference.shape:
        raise CalibrationError(
            f"{path}: imgs: expected uint8 (N, {', '.join(map(str, reference.shape))}), got {images.dtype} {images.shape}"
        )
    frame = str(members.get("frame", "raw"))
    if frame not in ("raw", "warped_cropped"):
        raise CalibrationError(f"{path}: frame = {frame!r}: expected 'raw' or 'warped_cropped'")
    stated = {}
    for name in ("mm_per_px", "ball_radius_mm"):
        if name in members:
            try:
                stated[name] = float(members[name])
            except (TypeError, ValueError) as exc:
                raise CalibrationError(f"{path}: {name} is not a number") from exc
            if not (math.isfinite(stated[name]) and stated[name] > 0):
                raise CalibrationError(f"{path}: {name} = {stated[name]!r}: expected a positive number")
    centers, radii = (_numbers(path, name, members[name]) for name in ("touch_center", "touch_radius"))
    if centers.shape != (len(images), 2) or radii.shape != (len(images),):
        raise CalibrationError(
            f"{path}: touch_center {centers.shape} / touch_radius {radii.shape} do not match {len(images)} images"
        )
    # Checked here, where the file and member can be named: later stages see only "radii_px".
    bad = np.flatnonzero(~np.isfinite(centers).all(axis=1))
    if bad.size:
        raise CalibrationError(
            f"{path}: touch_center: press {bad[0]} is {centers[bad[0]].tolist()} ({bad.size} of {len(centers)} "
            "not finite): expected finite (x, y) pixel centres"
        )
    bad = np.flatnonzero(~(np.isfinite(radii) & (radii > 0)))
    if bad.size:
        raise CalibrationError(
            f"{path}: touch_radius: press {bad[0]} is {radii[bad[0]]!r} ({bad.size} of {len(radii)} "
            "not positive and finite): expected positive contact radii in pixels"
        )
    return PressSet(reference, images, centers, radii, "recorded", frame, stated.get("mm_per_px"),
                    stated.get("ball_radius_mm"), str(path), _fingerprint(reference, images))


def _numbers(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    """The press file's member ``name`` as float64, or an error naming both."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{path}: {name}: expected numbers (pixels), got {value.dtype}") from exc


def _load_folder(path: Path, progress: bool) -> PressSet:
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    references = [p for p in files if REFERENCE_NAME.match(p.name)]
    if len(references) != 1:
        raise CalibrationError(
            f"{path}: expected exactly one no-contact image named f0*, ref* or background*, found "
            f"{[p.name for p in references] or 'none'}"
        )
    press_files = [p for p in files if p != references[0]]
    if not press_files:
        raise CalibrationError(f"{path}: no press images beside {references[0].name}")
    reference = _read_image(references[0])
    images = []
    for file in progress_bar(press_files, desc="reading presses", unit="image", enabled=progress):
        image = _read_image(file)
        if image.shape != reference.shape:
            raise CalibrationError(f"{file}: {image.shape} differs from the reference's {reference.shape}")
        images.append(image)
    stack = np.stack(images)
    return PressSet(reference, stack, None, None, "none", "raw", None, None, str(path),
                    _fingerprint(reference, stack))
