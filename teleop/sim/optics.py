"""Tactile optics of a simulated GelSight Wedge: gel height map in, raw camera frame out.

Frames
------
The mechanics work on the *grid*: the warped-and-cropped image the estimator sees,
``sensor.image_shape`` = (rows, cols) = (250, 350) pixels of ``sensor.pixel_pitch_m``,
x (columns) to the right, y (rows) down, z toward the camera. The camera sees the
*raw* frame (``raw_height_px`` x ``raw_width_px``, 480 x 640). The two are related by
the sensor's mirror-corner homography (:func:`raw_to_warped_matrix`: the raw corners
TL, TR, BL, BR go to the corners of the ``warped_width_px`` x ``warped_height_px``
image), after which ``crop_px`` pixels are cut from every side.

Optical model
-------------
The camera looks at the gel from behind, so an indentation ``h`` (m, into the gel)
moves the membrane toward the camera: the surface seen is z = h(x, y). Three
grazing coloured lights shine across the membrane as in the Wedge: green from the
left, red from the top, blue from the bottom, each at ``LIGHT_ELEVATION_RAD`` above
the gel. Each light's relative change of Lambertian radiance (plus a weak Phong
highlight) is computed from the surface normal, scaled by that light's irradiance
across the pad (a smooth, uneven gain field, fixed per sensor), mixed into BGR by
the LEDs' colour signatures, rendered on the warped image, mapped into raw pixels
through the inverse warp and added to the raw no-contact background. Outside the
pad's raw footprint the frame is the background, untouched.

For speed, the shading is tabulated once over surface slopes (a reflectance map)
and looked up per pixel with ``cv2.remap``; the height is blurred and
differentiated by one separable filter per axis; only the window of the warped
image where the gel moved (plus the filters' reach) is shaded and warped.

Marker dots (``sensor.markers``) are a dark texture printed on the gel; they are
advected with the in-plane surface displacement and darken the frame
multiplicatively.

This is an appearance model, not ray tracing: no refraction, no shadows cast by
the membrane, no multiple scattering. It is deterministic except for camera noise,
which is drawn from the camera's ``rng``.
"""

from __future__ import annotations

import functools
import zlib
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtri

from teleop.errors import SimulationError
from teleop.settings import CONFIG_DIR, SensorSettings, SimulationSettings

__all__ = [
    "TactileCamera",
    "load_background",
    "procedural_background",
    "raw_to_warped_matrix",
    "warp_to_grid",
]

LIGHT_ELEVATION_RAD = np.deg2rad(30.0)
# In-plane direction from the gel toward each light (x right, y down): left, top, bottom.
LIGHT_DIRECTIONS_XY = np.array([[-1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
# Camera BGR response to each light (columns: green-left, red-top, blue-bottom);
# LEDs are not spectrally pure, so each leaks a little into the other channels.
LIGHT_BGR = np.array(
    [[0.10, 0.05, 1.00],
     [1.00, 0.10, 0.20],
     [0.15, 1.00, 0.10]],
    dtype=np.float32,
)
# 8-bit levels per unit relative change of one light's radiance at full irradiance.
SHADING_GAIN_LEVELS = 80.0
SPECULAR_WEIGHT = 0.15
SPECULAR_EXPONENT = 8.0
# Reflectance map tabulated over surface slopes (dz/dx, dz/dy), looked up per pixel.
SLOPE_LIMIT = 4.0  # steeper slopes (above 76 degrees) shade like this one
REFLECTANCE_STEP = 0.02
# Gaussian blur of the height map (warped px): the membrane and the lens cannot
# reproduce a sharp slope discontinuity (e.g. the rim of a ball press).
MEMBRANE_BLUR_PX = 1.0
# Lens blur of the procedural background (raw px).
LENS_BLUR_PX = 0.8
# Beyond this many warped px from the moved gel, the blur, slopes and warp change nothing.
WINDOW_MARGIN_PX = 8
# Printed markers: a square grid of dark dots.
MARKER_SPACING_M = 1.5e-3
MARKER_RADIUS_M = 0.3e-3
MARKER_DARKNESS = 0.75
# Noise table entries are stored as unsigned bytes around this level.
NOISE_OFFSET = 128.0
# Derived in-plane flow when no shear is given: u = -gain * h * grad(h) (m).
DERIVED_SHEAR_GAIN = 1.0


def raw_to_warped_matrix(sensor: SensorSettings) -> np.ndarray:
    """Homography from raw camera pixels to the warped (uncropped) image.

    Maps the mirror corners ``warp_corners_px`` (TL, TR, BL, BR, raw px) to
    (0, 0), (W, 0), (0, H), (W, H) with W, H = ``warped_width_px``,
    ``warped_height_px`` (the GelSight SDK convention). Crop ``crop_px`` per side
    afterwards to reach the grid.

    Returns
    -------
    ndarray, shape (3, 3), float64
        For ``cv2.warpPerspective(raw, M, (W, H))``.
    """
    w, h = sensor.warped_width_px, sensor.warped_height_px
    src = np.array(sensor.warp_corners_px, dtype=np.float32)
    dst = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=np.float32)
    return cv2.getPerspectiveTransform(src, dst)


def warp_to_grid(raw: np.ndarray, sensor: SensorSettings) -> np.ndarray:
    """Warp a raw frame to the warped image and crop it to the grid.

    Parameters
    ----------
    raw : ndarray, shape (raw_height_px, raw_width_px[, C])
        Raw camera frame, any dtype OpenCV warps (dtype is kept).
    sensor : SensorSettings
        Supplies the corners, warped size and crop.

    Returns
    -------
    ndarray, shape sensor.image_shape (+ channels)
        Bilinear resampling; same dtype as ``raw``.
    """
    if raw.shape[:2] != (sensor.raw_height_px, sensor.raw_width_px):
        raise SimulationError(
            f"raw frame has shape {raw.shape}: expected "
            f"({sensor.raw_height_px}, {sensor.raw_width_px}[, channels]) for sensor {sensor.finger!r}"
        )
    warped = cv2.warpPerspective(
        raw, raw_to_warped_matrix(sensor), (sensor.warped_width_px, sensor.warped_height_px),
        flags=cv2.INTER_LINEAR,
    )
    c = sensor.crop_px
    return warped[c:warped.shape[0] - c, c:warped.shape[1] - c]


def load_background(path: str | Path) -> np.ndarray:
    """Read a no-contact raw frame (e.g. the real Wedge PNG) as uint8 BGR (H, W, 3)."""
    path = Path(path)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SimulationError(f"cannot read background image {path}: missing or not an image file")
    return image


def _sensor_seed(sensor: SensorSettings) -> int:
    """A stable seed per physical sensor: its illumination does not change between grasps."""
    return zlib.crc32(f"{sensor.model}/{sensor.finger}/{sensor.serial}".encode())


def _warped_coordinates(sensor: SensorSettings) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x, y) of the full warped image, float32 (H, W) each."""
    return np.meshgrid(
        np.arange(sensor.warped_width_px, dtype=np.float32),
        np.arange(sensor.warped_height_px, dtype=np.float32),
    )


def _smooth_gain(sensor: SensorSettings, *, amplitude: float) -> np.ndarray:
    """A smooth multiplicative field 1 +- ``amplitude`` across the warped image, fixed per sensor."""
    knots = np.random.default_rng(_sensor_seed(sensor)).uniform(-1.0, 1.0, (4, 5)).astype(np.float32)
    field = cv2.resize(knots, (sensor.warped_width_px, sensor.warped_height_px),
                       interpolation=cv2.INTER_CUBIC)
    return 1.0 + amplitude * np.clip(field, -1.0, 1.0)


def _vignette(sensor: SensorSettings) -> np.ndarray:
    """Radial fall-off of the whole pad's brightness (1 at the centre), float32 (H, W)."""
    x, y = _warped_coordinates(sensor)
    u = 2.0 * x / (sensor.warped_width_px - 1) - 1.0
    v = 2.0 * y / (sensor.warped_height_px - 1) - 1.0
    return (1.0 - 0.32 * u**2 - 0.12 * v**2).astype(np.float32)


def _edge_distances(sensor: SensorSettings) -> np.ndarray:
    """Distance (warped px) from the edge each light enters by: left, top, bottom. (3, H, W)."""
    x, y = _warped_coordinates(sensor)
    return np.stack([x, y, sensor.warped_height_px - 1 - y])


def _read_only(array: np.ndarray) -> np.ndarray:
    """Cached arrays are shared by every camera of a sensor: forbid writes."""
    array.flags.writeable = False
    return array


@functools.lru_cache(maxsize=8)
def _channel_gain(sensor: SensorSettings) -> np.ndarray:
    """Shading gain (levels per unit relative radiance change) per BGR channel, float32 (H, W, 3).

    Each light fades away from its edge (grazing light loses intensity across the
    pad), scaled by the sensor's fixed uneven-illumination field and the vignette.
    Each colour channel takes the field of the light that dominates it (the LEDs'
    small leaks into other channels follow that field too, which saves a colour
    transform per frame).
    """
    extent = np.array([sensor.warped_width_px, sensor.warped_height_px, sensor.warped_height_px],
                      dtype=np.float32)[:, None, None]
    fade = 0.6 + 0.4 * np.exp(-_edge_distances(sensor) / (0.5 * extent))
    irradiance = fade * _smooth_gain(sensor, amplitude=0.08) * _vignette(sensor)
    dominant = np.argmax(LIGHT_BGR, axis=1)
    gain = SHADING_GAIN_LEVELS * irradiance[dominant].transpose(1, 2, 0)
    return _read_only(np.ascontiguousarray(gain, dtype=np.float32))


@functools.cache
def _reflectance_map() -> np.ndarray:
    """BGR change per unit irradiance versus surface slope, float32 (n, n, 3).

    Entry [iy, ix] is for slopes (sx, sy) = (ix, iy) * REFLECTANCE_STEP - SLOPE_LIMIT.
    Each light k (green-left, red-top, blue-bottom) contributes its relative
    radiance change, Lambertian n.l / n0.l - 1 plus a weak Phong highlight toward
    the camera (zero on a flat gel), through its BGR signature ``LIGHT_BGR[:, k]``.
    The normal of the surface z = h(x, y) seen from the camera is n = (-sx, -sy, 1) / |.|.
    """
    slopes = np.arange(-SLOPE_LIMIT, SLOPE_LIMIT + REFLECTANCE_STEP / 2, REFLECTANCE_STEP)
    sx, sy = np.meshgrid(slopes, slopes)
    n_z = 1.0 / np.sqrt(1.0 + sx**2 + sy**2)
    sin_e, cos_e = np.sin(LIGHT_ELEVATION_RAD), np.cos(LIGHT_ELEVATION_RAD)
    per_light = []
    for lx, ly in LIGHT_DIRECTIONS_XY * cos_e:
        n_dot_l = np.maximum((sin_e - sx * lx - sy * ly) * n_z, 0.0)
        reflect_z = np.maximum(2.0 * n_dot_l * n_z - sin_e, 0.0)  # z of the mirrored light
        highlight = SPECULAR_WEIGHT * (reflect_z**SPECULAR_EXPONENT - sin_e**SPECULAR_EXPONENT)
        per_light.append(n_dot_l / sin_e - 1.0 + highlight)
    return _read_only(cv2.transform(np.stack(per_light, axis=-1).astype(np.float32), LIGHT_BGR))


@functools.lru_cache(maxsize=8)
def _marker_pattern(sensor: SensorSettings) -> np.ndarray:
    """Coverage (0..1, float32 (H, W)) of the printed marker dots at rest on the warped image."""
    x, y = _warped_coordinates(sensor)
    spacing = MARKER_SPACING_M / sensor.pixel_pitch_m
    offset = np.array([sensor.warped_width_px, sensor.warped_height_px]) % spacing / 2
    dx = (x - offset[0] + spacing / 2) % spacing - spacing / 2
    dy = (y - offset[1] + spacing / 2) % spacing - spacing / 2
    radius = MARKER_RADIUS_M / sensor.pixel_pitch_m
    return _read_only(np.clip(radius + 0.5 - np.hypot(dx, dy), 0.0, 1.0).astype(np.float32))


@functools.lru_cache(maxsize=8)
def _lit_housing(sensor: SensorSettings) -> np.ndarray:
    """The deterministic part of :func:`procedural_background`, float32 raw BGR, lens-blurred."""
    ww, wh = sensor.warped_width_px, sensor.warped_height_px
    distance = _edge_distances(sensor)
    pad = np.empty((wh, ww, 3), dtype=np.float32)
    pad[:] = np.array([145.0, 132.0, 110.0], dtype=np.float32)  # BGR of the real pad centre
    pad *= (_vignette(sensor) * _smooth_gain(sensor, amplitude=0.04))[..., None]
    # LED glow bands along the lit edges (decay lengths read off the real warped frame).
    glow = np.array([130.0, 80.0, 100.0], dtype=np.float32)[:, None, None] * np.exp(
        -distance / np.array([16.0, 28.0, 32.0], dtype=np.float32)[:, None, None]
    )
    pad += np.einsum("ck,khw->hwc", LIGHT_BGR, glow)
    # The green LED strip itself fills the left edge: blue and red fade there.
    pad[..., 0] *= 1.0 - 0.9 * np.exp(-distance[0] / 8.0)
    pad[..., 2] *= 1.0 - 0.3 * np.exp(-distance[0] / 8.0)

    size = (sensor.raw_width_px, sensor.raw_height_px)
    to_raw = np.linalg.inv(raw_to_warped_matrix(sensor))
    pad_raw = cv2.warpPerspective(pad, to_raw, size, flags=cv2.INTER_LINEAR)
    inside = cv2.warpPerspective(np.ones((wh, ww), np.float32), to_raw, size, flags=cv2.INTER_LINEAR)

    # Dark housing, a little brighter toward the bottom, and the second mirror view to the right.
    depth = np.linspace(0.0, 1.0, sensor.raw_height_px, dtype=np.float32)[:, None, None]
    frame = np.array([8.0, 8.0, 4.0], np.float32) + np.array([20.0, 9.0, 7.0], np.float32) * depth**2
    frame = np.broadcast_to(frame, (sensor.raw_height_px, sensor.raw_width_px, 3)).copy()
    corners = np.array(sensor.warp_corners_px, dtype=np.float32)
    gap = 0.1 * (corners[1, 0] - corners[0, 0])
    mirror = np.array(
        [corners[1] + (gap, -0.3 * gap), (sensor.raw_width_px + gap, corners[1, 1] - 3 * gap),
         corners[3] + (gap, 0.3 * gap), (sensor.raw_width_px + gap, corners[3, 1] + 3 * gap)],
        dtype=np.float32,
    )
    src = np.array([[0, 0], [ww, 0], [0, wh], [ww, wh]], dtype=np.float32)
    to_mirror = cv2.getPerspectiveTransform(src, mirror)
    mirror_raw = cv2.warpPerspective(0.55 * pad, to_mirror, size, flags=cv2.INTER_LINEAR)
    mirror_in = cv2.warpPerspective(np.ones((wh, ww), np.float32), to_mirror, size)
    frame += (mirror_raw - frame) * mirror_in[..., None]
    frame += (pad_raw - frame) * inside[..., None]
    return _read_only(cv2.GaussianBlur(frame, (0, 0), LENS_BLUR_PX))  # softens the pad's border


def procedural_background(sensor: SensorSettings, *, rng: np.random.Generator) -> np.ndarray:
    """A Wedge-like raw no-contact frame, uint8 BGR (raw_height_px, raw_width_px, 3).

    The pad (the raw footprint of the warped image) is a bright bluish-grey with
    a vignette, a green glow along its left edge, red along the top and blue
    along the bottom, as in the real Wedge frames; the sensor's uneven
    illumination is fixed per sensor (seeded from its model, finger and serial).
    Around the pad the frame is dark, with the dim second mirror view at the
    right. ``rng`` only scatters dust specks over the gel.
    """
    # Dust specks: single bright pixels on the gel, spread by the lens blur.
    n_specks = int(rng.integers(8, 20))
    on_gel = np.column_stack([rng.uniform(0, sensor.warped_width_px, n_specks),
                              rng.uniform(0, sensor.warped_height_px, n_specks)])
    raw_xy = cv2.perspectiveTransform(on_gel[:, None], np.linalg.inv(raw_to_warped_matrix(sensor)))[:, 0]
    cols = np.clip(np.rint(raw_xy[:, 0]).astype(int), 0, sensor.raw_width_px - 1)
    rows = np.clip(np.rint(raw_xy[:, 1]).astype(int), 0, sensor.raw_height_px - 1)
    specks = np.zeros((sensor.raw_height_px, sensor.raw_width_px), np.float32)
    np.add.at(specks, (rows, cols), rng.uniform(60.0, 140.0, n_specks).astype(np.float32))
    frame = _lit_housing(sensor) + cv2.GaussianBlur(specks, (0, 0), LENS_BLUR_PX)[..., None]
    return np.clip(np.rint(frame), 0, 255).astype(np.uint8)


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


class TactileCamera:
    """The camera of one simulated GelSight sensor: gel surface in, raw frames out.

    Parameters
    ----------
    sensor : SensorSettings
        Geometry (raw size, mirror corners, warp, crop, pixel pitch) and markers.
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
    When ``shear_m`` is not given, the gel surface is assumed to flow outward
    from the contact: u = -DERIVED_SHEAR_GAIN * h * grad(h) (m), which vanishes
    off contact and moves markers radially by a few pixels in a firm press.
    Shear only moves the markers; shading depends on the normals alone.
    """

    def __init__(self, sensor: SensorSettings, *, sim: SimulationSettings,
                 rng: np.random.Generator, background: np.ndarray | None = None) -> None:
        self.sensor = sensor
        self.sim = sim
        self.rng = rng
        raw_shape = (sensor.raw_height_px, sensor.raw_width_px, 3)
        if background is None:
            if sim.background:
                path = Path(sim.background)
                background = load_background(path if path.is_absolute() else CONFIG_DIR / path)
            else:
                background = procedural_background(sensor, rng=rng)
        background = np.asarray(background)
        if background.shape != raw_shape or background.dtype != np.uint8:
            raise SimulationError(
                f"background is {background.dtype} {background.shape}: expected uint8 {raw_shape} "
                f"(the raw frame of sensor {sensor.finger!r})"
            )
        self.background = _read_only(background.copy())

        self._to_warped = raw_to_warped_matrix(sensor)
        self._to_raw = np.linalg.inv(self._to_warped)
        self._reflectance = _reflectance_map()
        self._gain = _channel_gain(sensor)
        # Slopes of the membrane-blurred height (m), straight into reflectance-map coordinates:
        # one separable filter per axis (Gaussian blur and central difference folded together).
        gaussian = cv2.getGaussianKernel(2 * int(np.ceil(4 * MEMBRANE_BLUR_PX)) + 1, MEMBRANE_BLUR_PX)
        to_map = 1.0 / (sensor.pixel_pitch_m * REFLECTANCE_STEP)
        self._slope_kernels = (
            np.convolve(gaussian[:, 0], [0.25, 0.5, 0.25]).astype(np.float32),
            (to_map * np.convolve(gaussian[:, 0], [-0.5, 0.0, 0.5])).astype(np.float32),
        )
        self._map_origin = SLOPE_LIMIT / REFLECTANCE_STEP

        # The frame of the gel at rest; every render pastes a change onto it.
        self._rest_f32 = self.background.astype(np.float32)
        self.rest_frame = self.background
        if sensor.markers:
            self._grid_x, self._grid_y = _warped_coordinates(sensor)
            self._marker_rest = _marker_pattern(sensor)
            self._background_warped = cv2.warpPerspective(
                self._rest_f32, self._to_warped, (sensor.warped_width_px, sensor.warped_height_px),
                flags=cv2.INTER_LINEAR,
            )
            self._rest_warped = (1.0 - MARKER_DARKNESS * self._marker_rest[..., None]) * self._background_warped
            self.rest_frame = _read_only(self._paste(self._rest_warped - self._background_warped, (0, 0)))
            self._rest_f32 = self.rest_frame.astype(np.float32)

        # Camera noise: a 256-entry table of Gaussian quantiles (whole levels, offset by
        # NOISE_OFFSET) indexed by random bytes: a quantised normal with tails cut at
        # 2.7 s.d., an order of magnitude faster than drawing 900k normals per frame.
        quantiles = ndtri((np.arange(256) + 0.5) / 256.0)
        self._noise_table = np.clip(np.rint(NOISE_OFFSET + sim.camera_noise * quantiles),
                                    0, 255).astype(np.uint8)

    # ------------------------------------------------------------------ rendering

    def _padded(self, field: np.ndarray) -> np.ndarray:
        """Grid field -> full warped image; the gel beyond the crop continues the edge values."""
        c = self.sensor.crop_px
        return cv2.copyMakeBorder(field, c, c, c, c, cv2.BORDER_REPLICATE)

    def _paste(self, change: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        """Rest frame plus ``change`` (levels, a window of the warped image at ``origin`` (x, y)).

        Only the raw pixels the window can reach are resampled (bilinear, through
        the inverse warp); beyond the window the change is zero.
        """
        x0, y0 = origin
        rows, cols = change.shape[:2]
        reach = np.array([[[x0 - 1, y0 - 1]], [[x0 + cols, y0 - 1]],
                          [[x0 - 1, y0 + rows]], [[x0 + cols, y0 + rows]]], dtype=np.float64)
        corners = cv2.perspectiveTransform(reach, self._to_raw)[:, 0]
        rx0, ry0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
        rx1 = min(int(np.ceil(corners[:, 0].max())) + 1, self.sensor.raw_width_px)
        ry1 = min(int(np.ceil(corners[:, 1].max())) + 1, self.sensor.raw_height_px)
        frame = self.rest_frame.copy()
        if rx1 <= rx0 or ry1 <= ry0:
            return frame
        # raw window px -> change px, for WARP_INVERSE_MAP (no matrix inversion per frame).
        window_to_change = (
            np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
            @ self._to_warped
            @ np.array([[1.0, 0.0, rx0], [0.0, 1.0, ry0], [0.0, 0.0, 1.0]])
        )
        warped = cv2.warpPerspective(
            change, window_to_change, (rx1 - rx0, ry1 - ry0),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0.0,
        )
        window = (slice(ry0, ry1), slice(rx0, rx1))
        frame[window] = cv2.add(self._rest_f32[window], warped, dtype=cv2.CV_8U)
        return frame

    def _shading(self, height: np.ndarray, window: tuple[slice, slice]
                 ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """BGR change (levels, float32) of the warped image in ``window`` for surface z = height.

        Also returns the slopes as reflectance-map coordinates (map_x, map_y).
        """
        smooth, derivative = self._slope_kernels
        slope_map = (
            cv2.sepFilter2D(height, cv2.CV_32F, derivative, smooth, delta=self._map_origin),
            cv2.sepFilter2D(height, cv2.CV_32F, smooth, derivative, delta=self._map_origin),
        )
        relative = cv2.remap(self._reflectance, *slope_map, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        return cv2.multiply(relative, self._gain[window]), slope_map

    def _marker_alpha(self, height: np.ndarray, shear: np.ndarray | None,
                      slope_map: tuple[np.ndarray, np.ndarray], window: tuple[slice, slice]
                      ) -> np.ndarray:
        """Marker coverage (0..1, float32) in ``window`` after the gel surface moved in-plane."""
        # A point now at p came from about p - u(p): sample the printed pattern there.
        if shear is None:  # u = -gain * h * slope (m), so -u in px is gain * h * slope / pitch
            scale = DERIVED_SHEAR_GAIN * REFLECTANCE_STEP / self.sensor.pixel_pitch_m
            back_x, back_y = (cv2.multiply(m - self._map_origin, height, scale=scale) for m in slope_map)
        else:
            back_x, back_y = (shear[..., i] * (-1.0 / self.sensor.pixel_pitch_m) for i in (0, 1))
        map_x = cv2.add(self._grid_x[window], back_x)
        map_y = cv2.add(self._grid_y[window], back_y)
        return cv2.remap(self._marker_rest, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)

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
        shape = self.sensor.image_shape
        height = self._padded(_check_field(height_m, "height_m", shape))
        shear = None if shear_m is None else self._padded(_check_field(shear_m, "shear_m", (*shape, 2)))
        # Work only on the window where the gel moved (plus the blur's and slopes' reach):
        # everywhere else the change is exactly zero.
        moved = height != 0
        if shear is not None and self.sensor.markers:
            moved |= (shear != 0).any(axis=-1)
        rows, cols = np.flatnonzero(moved.any(axis=1)), np.flatnonzero(moved.any(axis=0))
        if rows.size == 0:
            return self.rest_frame.copy()
        y0, x0 = max(rows[0] - WINDOW_MARGIN_PX, 0), max(cols[0] - WINDOW_MARGIN_PX, 0)
        window = (slice(y0, rows[-1] + WINDOW_MARGIN_PX + 1), slice(x0, cols[-1] + WINDOW_MARGIN_PX + 1))
        height = height[window]
        change, slope_map = self._shading(height, window)
        if self.sensor.markers:
            coverage = self._marker_alpha(
                height, None if shear is None else shear[window], slope_map, window
            )
            transmitted = cv2.merge([1.0 - MARKER_DARKNESS * coverage] * 3)
            # (background + shading) * transmission - rest frame, in place.
            cv2.add(self._background_warped[window], change, dst=change)
            cv2.multiply(change, transmitted, dst=change)
            cv2.subtract(change, self._rest_warped[window], dst=change)
        return self._paste(change, (int(x0), int(y0)))

    def add_noise(self, frame: np.ndarray) -> np.ndarray:
        """``frame`` (uint8) plus camera noise of s.d. ``sim.camera_noise`` levels, saturated."""
        if frame.dtype != np.uint8:
            raise SimulationError(f"frame has dtype {frame.dtype}: expected a uint8 camera frame")
        if self.sim.camera_noise == 0:
            return frame.copy()
        # random_raw: ten times faster than Generator.bytes, and as reproducible.
        words = self.rng.bit_generator.random_raw(-(-frame.size // 8))
        indices = words.view(np.uint8)[:frame.size].reshape(frame.shape)
        noise = cv2.LUT(indices, self._noise_table)
        return cv2.addWeighted(frame, 1.0, noise, 1.0, -NOISE_OFFSET)

    def capture(self, height_m, *, shear_m=None) -> bytes:
        """One camera frame as the sensor delivers it: render, noise, JPEG at ``sim.jpeg_quality``.

        Same inputs as :meth:`render`; returns the JPEG bytes (decode with
        ``cv2.imdecode`` to uint8 BGR of the raw shape).
        """
        frame = self.add_noise(self.render(height_m, shear_m=shear_m))
        ok, encoded = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, self.sim.jpeg_quality])
        if not ok:
            raise SimulationError(f"JPEG encoding of a {frame.shape} frame failed")
        return encoded.tobytes()
