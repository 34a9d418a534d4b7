"""The grid depth is measured on: a sensor's image grid (a Wedge's warped and cropped), or that grid binned.

With :attr:`~estimator.settings.EstimatorSettings.depth_binning` K > 1 the estimator measures
depth on the image grid averaged over K x K px blocks: a frame is decoded K times smaller
(:func:`~teleop.record.decode_image`; a JPEG at that size), warped straight onto the binned
grid (:func:`~estimator.perception.warp.warp_and_crop` with ``binning``), and its depth is
reconstructed with the calibration's colour-to-gradient table at K times the pixel pitch
(:func:`grid_calibration`). The colour lookup, the Poisson solve and the contact features
then see K^2 times fewer pixels.

The grid is described by a :class:`DepthGrid` (:func:`depth_grid`): its shape, its pixel pitch
(K times the sensor's, covering the same pad), and what depth and contact features read of the
sensor there (the contact threshold, whether the gel has markers), at any K, 1 included.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from estimator.errors import PerceptionError
from estimator.perception.calibration import Calibration
from estimator.perception.warp import check_binning, check_raw_frame, warp_and_crop
from teleop.record import decode_image, reduce_image
from teleop.settings import SensorSettings

__all__ = ["ENCODINGS", "DepthGrid", "decode_frame", "depth_grid", "frame_on_grid", "grid_calibration", "raw_frame", "to_grid"]

# How a captured frame may come: encoded as the camera gave it, or as a raw BGR image.
ENCODINGS = ("jpeg", "png", "raw")


@dataclass(frozen=True)
class DepthGrid:
    """The grid depth is measured on: ``image_shape`` (rows, cols) px of ``pixel_pitch_m``, the
    sensor's image grid binned by ``binning``; ``contact_threshold_m`` and ``markers`` are the
    sensor's (contact features and marker masking read them)."""

    image_shape: tuple[int, int]
    pixel_pitch_m: float
    binning: int
    contact_threshold_m: float
    markers: bool

    @property
    def pad_size_m(self) -> tuple[float, float]:
        """(height, width) of the gel area the grid covers, in metres (the sensor's at any binning)."""
        rows, cols = self.image_shape
        return (rows * self.pixel_pitch_m, cols * self.pixel_pitch_m)


@functools.lru_cache(maxsize=32, typed=True)  # typed: True is no binning 1
def depth_grid(sensor: SensorSettings, binning: int) -> DepthGrid:
    """The depth grid of ``sensor`` binned by ``binning``: its image grid ``binning`` times coarser,
    at ``binning`` times the pixel pitch (the same pad); one object per sensor and binning.

    Raises
    ------
    PerceptionError
        ``binning`` does not divide the sensor's image grid and raw frame, or it is above 1 and
        the sensor has markers (their dots are found and inpainted on the full grid):
        :func:`~estimator.perception.warp.check_binning`.
    """
    check_binning(sensor, binning)
    rows, cols = (side // binning for side in sensor.image_shape)
    return DepthGrid(image_shape=(rows, cols), pixel_pitch_m=sensor.pixel_pitch_m * binning, binning=binning,
                     contact_threshold_m=sensor.contact_threshold_m, markers=sensor.markers)


def grid_calibration(calibration: Calibration, binning: int) -> Calibration:
    """``calibration`` on its grid ``binning`` times coarser: the same colour-to-gradient table (each
    tile keeps its share of the image) at ``binning`` times the pixel pitch, its smoothing ``binning``
    times fewer pixels (the same on the gel); itself for ``binning`` 1.
    One object per calibration and binning (the depth solver's tables are cached per grid).

    Raises PerceptionError when ``binning`` does not divide both sides of its grid.
    """
    check_binning(None, binning, grid_shape=calibration.image_shape)
    return calibration if binning == 1 else _binned_calibration(calibration, binning)


@functools.lru_cache(maxsize=8)
def _binned_calibration(calibration: Calibration, binning: int) -> Calibration:
    rows, cols = (side // binning for side in calibration.image_shape)
    return Calibration(lut=calibration.lut, image_shape=(rows, cols), pixel_pitch_m=calibration.pixel_pitch_m * binning,
                       ball_radius_m=calibration.ball_radius_m, relative_range=calibration.relative_range,
                       smoothing_px=calibration.smoothing_px / binning,
                       provenance={**calibration.provenance, "binned": binning})


def to_grid(image: np.ndarray, sensor: SensorSettings, *, binning: int) -> np.ndarray:
    """A raw frame of ``sensor`` decoded ``binning`` times smaller, on the depth grid: warped and cropped
    for a Wedge (:func:`~estimator.perception.warp.warp_and_crop`), as it is otherwise.

    Returns uint8 ``sensor.image_shape // binning + (3,)`` BGR. Raises PerceptionError, as
    :func:`~estimator.perception.warp.warp_and_crop` does, when ``binning`` is not one for the sensor
    (:func:`~estimator.perception.warp.check_binning`: it divides both sides of its image grid and raw
    frame) or ``image`` is not a uint8 BGR frame of the sensor's raw size over ``binning``
    (:func:`~estimator.perception.warp.check_raw_frame`).
    """
    if sensor.model == "wedge":
        return warp_and_crop(image, sensor, binning=binning)
    # A side binning does not divide is rounded when decoded smaller: not the grid's K x K px blocks.
    check_binning(sensor, binning)
    check_raw_frame(image, sensor, binning=binning, name="image")
    return image


def raw_frame(data: bytes | np.ndarray, *, where: str = "frame") -> np.ndarray:
    """A frame that came ``raw``: ``data`` itself when it is a uint8 H x W x 3 BGR image, else
    PerceptionError naming ``where``."""
    image = np.asarray(data)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise PerceptionError(f"{where}: raw frame must be uint8 H x W x 3 BGR, got {image.dtype} {image.shape}")
    return image


def decode_frame(data: bytes | np.ndarray, encoding: str, sensor: SensorSettings, *, binning: int,
                 where: str = "frame") -> np.ndarray:
    """One captured frame of ``sensor`` decoded ``binning`` times smaller, as captured (uint8 BGR).

    Parameters
    ----------
    data : bytes or ndarray
        ``jpeg``/``png``: the encoded bytes (1-D uint8); ``raw``: the H x W x 3 uint8 BGR image.
    encoding : {"jpeg", "png", "raw"}
    sensor : SensorSettings
    binning : int
    where : str
        Names the frame in errors.

    Raises
    ------
    PerceptionError
        ``binning`` does not divide both sides of the sensor's raw frame, unknown encoding, bytes that
        do not decode or declare another size than the sensor's raw frame (refused before decoding),
        a raw image that is not uint8 BGR.
    """
    try:  # a JPEG or PNG decoded smaller rounds a side binning does not divide: not K x K px blocks
        check_binning(None, binning, grid_shape=(sensor.raw_height_px, sensor.raw_width_px))
    except PerceptionError as exc:
        raise PerceptionError(f"{where}: {exc} (the raw frame of finger {sensor.finger!r})") from exc
    if encoding == "raw":
        image = raw_frame(data, where=where)
        try:
            return reduce_image(image, binning)
        except ValueError as exc:
            raise PerceptionError(f"{where}: {exc}") from exc
    if encoding not in ("jpeg", "png"):
        raise PerceptionError(f"{where}: encoding {encoding!r}, expected one of {', '.join(ENCODINGS)}")
    try:
        # The sensor's size, checked in the header before decoding: a few bytes may declare gigabytes.
        image = decode_image(data, reduce=binning, shape=(sensor.raw_height_px, sensor.raw_width_px))
    except ValueError as exc:
        raise PerceptionError(f"{where}: {exc}") from exc
    if image is None:
        raise PerceptionError(f"{where}: {encoding} data does not decode")
    return image


def frame_on_grid(data: bytes | np.ndarray, encoding: str, sensor: SensorSettings, *, binning: int,
                  where: str = "frame") -> np.ndarray:
    """One captured frame of ``sensor`` on the depth grid: :func:`decode_frame`, then :func:`to_grid`.

    Raises
    ------
    PerceptionError
        As :func:`decode_frame`, or a raw image not of the sensor's raw size.
    """
    image = decode_frame(data, encoding, sensor, binning=binning, where=where)
    try:
        return to_grid(image, sensor, binning=binning)
    except PerceptionError as exc:
        raise PerceptionError(f"{where}: {exc}") from exc
