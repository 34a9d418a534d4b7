"""Tactile optics of a simulated GelSight sensor: gel height map in, raw camera frame out.

:class:`OpticsRenderer` is the camera of one simulated sensor: it takes the gel's
indentation on the sensor's grid (:mod:`teleop.sim.camera_geometry` has the frames)
and gives the raw frame the camera delivers, with printed markers, camera noise and
JPEG. Its shading is the Wedge's analytic model (:mod:`teleop.sim.wedge_optics`), or
a real sensor's measured colour tables (:mod:`teleop.sim.table_optics`).

Rendering
---------
The surface change is shaded onto the raw no-contact background, scaled by
``sim.illumination_gain`` (LED current and ageing: 1 as calibrated). Each raw
pixel of the pad is shaded from the slopes at the point of the warped image it sees
(through :func:`~teleop.sim.camera_geometry.pad_view`: a Wedge's mirror-corner
homography, a flat sensor's identity); outside the pad's raw footprint the frame is
the background, untouched.

For speed, the shading is looked up per pixel with ``cv2.remap`` in a table over
surface slopes (the reflectance map); the height is blurred and
differentiated by one separable filter per axis; only the raw pixels that see the
window of the warped image where the gel moved (plus the filters' reach) are
shaded. A series of frames whose surfaces mix a few basis surfaces
(:meth:`OpticsRenderer.render_series`, e.g. a grasp's force levels) filters and
resamples each basis once, mixes their slopes per frame, and renders each distinct
mix once.

Marker dots (``sensor.markers``) are a dark texture printed on the gel; they are
advected with the in-plane surface displacement and darken the frame
multiplicatively.

This is an appearance model, not ray tracing: no refraction, no shadows cast by
the membrane, no multiple scattering. It is deterministic except for camera noise,
which is drawn from the camera's ``rng``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtri

from teleop.errors import SimulationError
from teleop.settings import SensorSettings, SimulationSettings, resolve_path
from teleop.sim.camera_geometry import (
    pad_view,
    raw_footprint,
    read_only,
    sample_warped,
    warped_coordinates,
)
from teleop.sim.wedge_optics import (
    REFLECTANCE_STEP,
    SLOPE_LIMIT,
    channel_gain,
    procedural_background,
    reflectance_map,
)

__all__ = [
    "OpticsRenderer",
    "load_background",
]

# Gaussian blur of the height map (warped px): the membrane and the lens cannot
# reproduce a sharp slope discontinuity (e.g. the rim of a ball press).
MEMBRANE_BLUR_PX = 1.0
# Beyond this many warped px from the moved gel, the blur, slopes and warp change nothing.
WINDOW_MARGIN_PX = 8
# Printed markers: a square grid of dark dots.
MARKER_SPACING_M = 1.5e-3
MARKER_RADIUS_M = 0.3e-3
MARKER_DARKNESS = 0.75
# Noise table entries are stored as unsigned bytes around this level.
NOISE_OFFSET = 128.0
# Noise values in a camera's pool beyond one frame's: the number of distinct frame offsets.
NOISE_POOL_EXTRA = 1 << 20
# Derived in-plane flow when no shear is given: u = -gain * h * grad(h) (m).
DERIVED_SHEAR_GAIN = 1.0


def load_background(path: str | Path) -> np.ndarray:
    """Read a no-contact raw frame (e.g. the real Wedge PNG) as uint8 BGR (H, W, 3)."""
    path = Path(path)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SimulationError(f"cannot read background image {path}: missing or not an image file")
    return image


@functools.lru_cache(maxsize=8)
def _marker_pattern(sensor: SensorSettings) -> np.ndarray:
    """Coverage (0..1, float32 (H, W)) of the printed marker dots at rest on the warped image."""
    x, y = warped_coordinates(sensor)
    spacing = MARKER_SPACING_M / sensor.pixel_pitch_m
    view = pad_view(sensor)
    offset = np.array([view.width_px, view.height_px]) % spacing / 2
    dx = (x - offset[0] + spacing / 2) % spacing - spacing / 2
    dy = (y - offset[1] + spacing / 2) % spacing - spacing / 2
    radius = MARKER_RADIUS_M / sensor.pixel_pitch_m
    return read_only(np.clip(radius + 0.5 - np.hypot(dx, dy), 0.0, 1.0).astype(np.float32))


@functools.lru_cache(maxsize=8)
def _raw_gain(sensor: SensorSettings) -> np.ndarray:
    """:func:`channel_gain` seen by the raw pixels of :func:`raw_footprint`'s box; 0 off the pad."""
    _, map_x, map_y = raw_footprint(sensor)
    return read_only(sample_warped(channel_gain(sensor), map_x, map_y))


@functools.lru_cache(maxsize=8)
def _raw_marker_coverage(sensor: SensorSettings) -> np.ndarray:
    """:func:`_marker_pattern` at rest seen by the raw pixels of the footprint box."""
    _, map_x, map_y = raw_footprint(sensor)
    return read_only(sample_warped(_marker_pattern(sensor), map_x, map_y))


def _check_field(value, name: str, shape: tuple[int, ...]) -> np.ndarray:
    array = np.asarray(value)
    if array.shape != shape:
        raise SimulationError(f"{name} has shape {array.shape}: expected {shape}")
    if not np.issubdtype(array.dtype, np.floating) and not np.issubdtype(array.dtype, np.integer):
        raise SimulationError(f"{name} has dtype {array.dtype}: expected real numbers in metres")
    array = array.astype(np.float32)
    if not np.isfinite(array).all():
        raise SimulationError(f"{name} contains NaN or infinite values: expected finite metres")
    return array


def _mix(fields: list[np.ndarray], weights: np.ndarray, active: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """offset + sum over ``active`` k of weights[k] * fields[k], float32."""
    mixed = np.full_like(fields[active[0]], offset)
    for k in active:
        cv2.scaleAdd(fields[k], float(weights[k]), mixed, dst=mixed)
    return mixed


class _Series:
    """A camera's view of K basis surfaces, prepared once for a series of frames mixing them.

    Everything is on the raw pixels ``box`` can change: slopes (reflectance-map
    units), in-plane displacement toward where a marker came from (warped px) and
    height (m), each per basis (None for bases no frame uses); the warped
    coordinates of the box's pixels, the shading gain and the rest values there.
    """

    def __init__(self, camera: OpticsRenderer, heights: np.ndarray, shears: np.ndarray | None,
                 used: np.ndarray) -> None:
        sensor = camera.sensor
        padded_heights = {k: camera._padded(heights[k]) for k in used}
        padded_shears = {} if shears is None or not sensor.markers else {
            k: camera._padded(shears[k]) for k in used}
        view = pad_view(sensor)
        moved = np.zeros((view.height_px, view.width_px), bool)
        for k in used:
            moved |= padded_heights[k] != 0
            if k in padded_shears:
                moved |= (padded_shears[k] != 0).any(axis=-1)
        rows, cols = np.flatnonzero(moved.any(axis=1)), np.flatnonzero(moved.any(axis=0))
        self.box = None
        if rows.size == 0:
            return  # nothing moved: every frame is the rest frame
        # Work only where the gel moved, plus the blur's, slopes' and bilinear samples' reach.
        y0, x0 = max(rows[0] - WINDOW_MARGIN_PX, 0), max(cols[0] - WINDOW_MARGIN_PX, 0)
        y1, x1 = rows[-1] + WINDOW_MARGIN_PX + 1, cols[-1] + WINDOW_MARGIN_PX + 1
        window = (slice(y0, y1), slice(x0, x1))
        (fy, fx), foot_x, foot_y = raw_footprint(sensor)
        inside = ((foot_x >= x0 - 1) & (foot_x <= x1) & (foot_y >= y0 - 1) & (foot_y <= y1))
        box_rows, box_cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
        if box_rows.size == 0:
            return
        local = (slice(box_rows[0], box_rows[-1] + 1), slice(box_cols[0], box_cols[-1] + 1))
        self.box = (slice(fy.start + local[0].start, fy.start + local[0].stop),
                    slice(fx.start + local[1].start, fx.start + local[1].stop))
        self.map_x, self.map_y = foot_x[local], foot_y[local]  # warped px of the whole image
        window_x, window_y = self.map_x - np.float32(x0), self.map_y - np.float32(y0)
        self.gain = _raw_gain(sensor)[local]
        self.rest = camera._rest_f32[self.box]
        if sensor.markers:
            self.background = camera._background_f32[self.box]
            self.marked = camera._marked_f32[self.box]

        smooth, derivative = camera._slope_kernels
        k_count = heights.shape[0]
        self.slope_x: list[np.ndarray | None] = [None] * k_count
        self.slope_y: list[np.ndarray | None] = [None] * k_count
        self.height: list[np.ndarray | None] = [None] * k_count
        self.back_x: list[np.ndarray | None] | None = [None] * k_count if padded_shears else None
        self.back_y: list[np.ndarray | None] | None = [None] * k_count if padded_shears else None
        to_px = -1.0 / sensor.pixel_pitch_m  # a point now at p came from about p - u(p)
        for k in used:
            height = padded_heights[k][window]
            self.slope_x[k] = sample_warped(cv2.sepFilter2D(height, cv2.CV_32F, derivative, smooth),
                                      window_x, window_y)
            self.slope_y[k] = sample_warped(cv2.sepFilter2D(height, cv2.CV_32F, smooth, derivative),
                                      window_x, window_y)
            if self.back_x is not None:
                shear = padded_shears[k][window]
                self.back_x[k] = sample_warped(np.ascontiguousarray(shear[..., 0]) * to_px, window_x, window_y)
                self.back_y[k] = sample_warped(np.ascontiguousarray(shear[..., 1]) * to_px, window_x, window_y)
            elif sensor.markers:
                self.height[k] = sample_warped(height, window_x, window_y)


class OpticsRenderer:
    """The simulated optics and camera of one GelSight sensor: gel surface in, raw frames out.

    Parameters
    ----------
    sensor : SensorSettings
        Geometry (raw size, pixel pitch and, for a Wedge, mirror corners, warp and crop) and markers.
    sim : SimulationSettings
        ``camera_noise`` (pixel noise s.d., 8-bit levels), ``jpeg_quality`` and,
        when ``background`` is None, ``background`` (PNG path; relative paths are
        under configs/; empty means :func:`procedural_background`).
    rng : numpy.random.Generator
        Source of camera noise (and of the procedural background's dust). The
        same seed gives the same bytes.
    background : ndarray, optional
        Raw uint8 BGR no-contact frame of shape (raw_height_px, raw_width_px, 3).

    Attributes
    ----------
    background : ndarray
        The no-contact frame in use (read-only copy).
    rest_frame : ndarray
        What :meth:`render` gives for an untouched gel: the background, with the
        marker dots at rest when the sensor has markers (read-only).

    Notes
    -----
    Each raw pixel of the pad is shaded from the surface slopes at the point of
    the warped image it sees (bilinear samples of the slope field), so the
    shading is computed once per raw pixel with no resampling of the result.

    When ``shear_m`` is not given, the gel surface is assumed to flow outward
    from the contact: u = -DERIVED_SHEAR_GAIN * h * grad(h) (m), which vanishes
    off contact and moves markers radially by a few pixels in a firm press.
    Shear only moves the markers; shading depends on the normals alone.

    Camera noise is read from a pool of ``NOISE_POOL_EXTRA`` + one frame's worth
    of independent quantised Gaussian values, drawn from ``rng`` when the camera
    is built; each frame takes the pool from a fresh random offset (never one
    used before by this camera), so a pixel's noise is independent between
    frames and between pixels, at a fraction of the cost of fresh draws.

    ``OpticsRenderer(sensor, ...)`` builds the camera of ``sensor.optics``: this
    Wedge model for ``"wedge"``, a
    :class:`~teleop.sim.table_optics.TableCamera` (same interface, the measured
    colour tables of a real sensor) otherwise.
    """

    def __new__(cls, *args, **kwargs):
        sensor = args[0] if args else kwargs.get("sensor")
        if cls is OpticsRenderer and getattr(sensor, "optics", "wedge") != "wedge":
            from teleop.sim.table_optics import TableCamera  # imports this module

            return super().__new__(TableCamera)
        return super().__new__(cls)

    def __init__(self, sensor: SensorSettings, *, sim: SimulationSettings,
                 rng: np.random.Generator, background: np.ndarray | None = None) -> None:
        self.sensor = sensor
        self.sim = sim
        self.rng = rng
        raw_shape = (sensor.raw_height_px, sensor.raw_width_px, 3)
        if background is None:
            if sim.background:
                background = load_background(resolve_path(sim.background))
            else:
                background = procedural_background(sensor, rng=rng)
        background = np.asarray(background)
        if background.shape != raw_shape or background.dtype != np.uint8:
            raise SimulationError(
                f"background is {background.dtype} {background.shape}: expected uint8 {raw_shape} "
                f"(the raw frame of sensor {sensor.finger!r})"
            )
        self.background = read_only(background.copy())

        self._reflectance = reflectance_map()
        # Slopes of the membrane-blurred height (m), straight into reflectance-map units:
        # one separable filter per axis (Gaussian blur and central difference folded together).
        gaussian = cv2.getGaussianKernel(2 * int(np.ceil(4 * MEMBRANE_BLUR_PX)) + 1, MEMBRANE_BLUR_PX)
        to_map = 1.0 / (sensor.pixel_pitch_m * REFLECTANCE_STEP)
        self._slope_kernels = (
            np.convolve(gaussian[:, 0], [0.25, 0.5, 0.25]).astype(np.float32),
            (to_map * np.convolve(gaussian[:, 0], [-0.5, 0.0, 0.5])).astype(np.float32),
        )
        self._map_origin = SLOPE_LIMIT / REFLECTANCE_STEP

        # The frame of the gel at rest; every render pastes a change onto it.
        self._background_f32 = self.background.astype(np.float32)
        self.rest_frame = self.background
        if sensor.markers:
            self._marker_rest = _marker_pattern(sensor)
            box = raw_footprint(sensor)[0]
            transmitted = 1.0 - MARKER_DARKNESS * _raw_marker_coverage(sensor)
            self._marked_f32 = self._background_f32.copy()  # before rounding: renders add a change to it
            self._marked_f32[box] *= cv2.merge([transmitted] * 3)
            self.rest_frame = read_only(np.clip(np.rint(self._marked_f32), 0, 255).astype(np.uint8))
        self._rest_f32 = self.rest_frame.astype(np.float32)

        # Camera noise: a 256-entry table of Gaussian quantiles (whole levels, offset by
        # NOISE_OFFSET) indexed by random bytes gives a quantised normal with tails cut at
        # 2.7 s.d.; a pool of such values serves every frame (see Notes).
        quantiles = ndtri((np.arange(256) + 0.5) / 256.0)
        table = np.clip(np.rint(NOISE_OFFSET + sim.camera_noise * quantiles), 0, 255).astype(np.uint8)
        size = int(np.prod(raw_shape)) + NOISE_POOL_EXTRA
        # random_raw: ten times faster than Generator.bytes, and as reproducible.
        indices = rng.bit_generator.random_raw(-(-size // 8)).view(np.uint8)[:size]
        self._noise_pool = cv2.LUT(indices, table).ravel()
        self._noise_offsets_used: set[int] = set()

    # ------------------------------------------------------------------ rendering

    def _padded(self, field: np.ndarray) -> np.ndarray:
        """Grid field -> full warped image; the gel beyond the crop continues the edge values."""
        c = pad_view(self.sensor).crop_px
        return cv2.copyMakeBorder(field, c, c, c, c, cv2.BORDER_REPLICATE)

    def _series(self, height_m, shear_m, used: np.ndarray, *, batch: bool) -> _Series:
        shape = self.sensor.image_shape
        heights = _check_field(height_m, "height_m", (len(np.asarray(height_m)), *shape) if batch else shape)
        shears = None if shear_m is None else _check_field(
            shear_m, "shear_m", (*heights.shape, 2))
        if not batch:
            heights, shears = heights[None], None if shears is None else shears[None]
        return _Series(self, heights, shears, used)

    def _shade(self, series: _Series, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
        """BGR change (8-bit levels, float32, ``series.box``'s shape) of the gel with the slopes
        ``map_x``, ``map_y`` (reflectance-map coordinates), scaled by ``sim.illumination_gain``."""
        relative = cv2.remap(self._reflectance, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        gain = self.sim.illumination_gain
        return cv2.multiply(relative, series.gain) if gain == 1.0 else cv2.multiply(relative, series.gain, scale=gain)

    def _draw(self, series: _Series, weights: np.ndarray) -> np.ndarray:
        """Clean raw frame of the surface sum_k weights[k] * basis k of ``series``."""
        active = np.flatnonzero(weights)
        if series.box is None or active.size == 0:
            return self.rest_frame.copy()
        map_x = _mix(series.slope_x, weights, active, self._map_origin)
        map_y = _mix(series.slope_y, weights, active, self._map_origin)
        change = self._shade(series, map_x, map_y)
        frame = self.rest_frame.copy()
        if not self.sensor.markers:
            frame[series.box] = cv2.add(series.rest, change, dtype=cv2.CV_8U)
            return frame
        if series.back_x is not None:
            back_x, back_y = (_mix(b, weights, active) for b in (series.back_x, series.back_y))
        else:  # u = -gain * h * slope (m), so -u in px is gain * h * slope / pitch
            height = _mix(series.height, weights, active)
            scale = DERIVED_SHEAR_GAIN * REFLECTANCE_STEP / self.sensor.pixel_pitch_m
            back_x, back_y = (cv2.multiply(m - self._map_origin, height, scale=scale) for m in (map_x, map_y))
        coverage = sample_warped(self._marker_rest, cv2.add(series.map_x, back_x), cv2.add(series.map_y, back_y))
        transmitted = cv2.merge([1.0 - MARKER_DARKNESS * coverage] * 3)
        # (background + shading) * transmission - marked background at rest, pasted on the rest frame:
        # a change well below a level leaves the pixel as it is at rest.
        cv2.add(series.background, change, dst=change)
        cv2.multiply(change, transmitted, dst=change)
        cv2.subtract(change, series.marked, dst=change)
        frame[series.box] = cv2.add(series.rest, change, dtype=cv2.CV_8U)
        return frame

    def render(self, height_m, *, shear_m=None) -> np.ndarray:
        """Clean raw frame of the gel indented by ``height_m``.

        Parameters
        ----------
        height_m : array_like, shape sensor.image_shape
            Gel indentation (m, positive into the gel, i.e. toward the camera) on
            the grid; negative values are the membrane bulging outward.
        shear_m : array_like, shape sensor.image_shape + (2,), optional
            In-plane displacement of the gel surface (m), [d_col, d_row] on the
            grid. Only moves the markers; None derives an outward flow (see Notes
            of the class).

        Returns
        -------
        ndarray, uint8, shape (raw_height_px, raw_width_px, 3)
            BGR raw frame, no noise. A zero height map gives :attr:`rest_frame`:
            the background, with the markers at rest when the sensor has them.
        """
        one = np.ones(1)
        return self._draw(self._series(height_m, shear_m, np.flatnonzero(one), batch=False), one)

    def render_series(self, height_m, weights, *, shear_m=None) -> list[np.ndarray]:
        """Clean raw frames of surfaces that mix a few basis surfaces linearly.

        Frame n shows the surface sum_k weights[n, k] * height_m[k] (and the
        same mix of ``shear_m``), exactly as :meth:`render` would. The blur,
        slopes and in-plane displacement are linear in the surface, so they are
        computed once per basis; frames with equal weights share one render.

        Parameters
        ----------
        height_m : array_like, shape (K,) + sensor.image_shape
            Basis indentations (m), as for :meth:`render`.
        weights : array_like, shape (N, K)
            Finite mixing weights; a row of zeros is the gel at rest.
        shear_m : array_like, shape (K,) + sensor.image_shape + (2,), optional
            Basis in-plane displacements (m); None derives them per frame.

        Returns
        -------
        list of N ndarray, uint8, shape (raw_height_px, raw_width_px, 3)
            The frames; equal rows of ``weights`` give the same array object.
        """
        weights = np.asarray(weights, dtype=np.float64)
        k_count = len(np.asarray(height_m))
        if weights.ndim != 2 or weights.shape[1] != k_count or not np.isfinite(weights).all():
            raise SimulationError(f"weights has shape {weights.shape}: expected finite (frames, {k_count}) "
                                  "mixing weights, one column per basis surface")
        distinct, which = np.unique(weights, axis=0, return_inverse=True)
        series = self._series(height_m, shear_m, np.flatnonzero(distinct.any(axis=0)), batch=True)
        frames = [self._draw(series, row) for row in distinct]
        return [frames[i] for i in which.ravel()]

    def add_noise(self, frame: np.ndarray) -> np.ndarray:
        """``frame`` (uint8) plus camera noise of s.d. ``sim.camera_noise`` levels, saturated."""
        if frame.dtype != np.uint8:
            raise SimulationError(f"frame has dtype {frame.dtype}: expected a uint8 camera frame")
        if frame.size + NOISE_POOL_EXTRA > self._noise_pool.size:
            raise SimulationError(f"frame has shape {frame.shape}: larger than the camera's raw frame")
        if self.sim.camera_noise == 0:
            return frame.copy()
        offset = int(self.rng.integers(self._noise_pool.size - frame.size + 1))
        while offset in self._noise_offsets_used:  # never the same noise twice
            offset = int(self.rng.integers(self._noise_pool.size - frame.size + 1))
        self._noise_offsets_used.add(offset)
        noise = self._noise_pool[offset:offset + frame.size].reshape(frame.shape)
        return cv2.addWeighted(frame, 1.0, noise, 1.0, -NOISE_OFFSET)

    def _encode(self, frame: np.ndarray) -> bytes:
        ok, encoded = cv2.imencode(".jpg", self.add_noise(frame),
                                   [cv2.IMWRITE_JPEG_QUALITY, self.sim.jpeg_quality])
        if not ok:
            raise SimulationError(f"JPEG encoding of a {frame.shape} frame failed")
        return encoded.tobytes()

    def capture(self, height_m, *, shear_m=None) -> bytes:
        """One camera frame as the sensor delivers it: render, noise, JPEG at ``sim.jpeg_quality``.

        Same inputs as :meth:`render`; returns the JPEG bytes (decode with
        ``cv2.imdecode`` to uint8 BGR of the raw shape).
        """
        return self._encode(self.render(height_m, shear_m=shear_m))

    def capture_series(self, height_m, weights, *, shear_m=None) -> list[bytes]:
        """Camera frames of mixed basis surfaces (see :meth:`render_series`), each with its own noise.

        Returns one JPEG per row of ``weights``, in order.
        """
        return [self._encode(frame) for frame in self.render_series(height_m, weights, shear_m=shear_m)]
