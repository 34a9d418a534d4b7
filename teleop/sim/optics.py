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
the LEDs' colour signatures, scaled by ``sim.illumination_gain`` (LED current and
ageing: 1 as calibrated) and added to the raw no-contact background. Each raw
pixel of the pad is shaded from the slopes at the point of the warped image it sees
(through the mirror-corner homography); outside the pad's raw footprint the frame is
the background, untouched.

For speed, the shading is tabulated once over surface slopes (a reflectance map)
and looked up per pixel with ``cv2.remap``; the height is blurred and
differentiated by one separable filter per axis; only the raw pixels that see the
window of the warped image where the gel moved (plus the filters' reach) are
shaded. A series of frames whose surfaces mix a few basis surfaces
(:meth:`TactileCamera.render_series`, e.g. a grasp's force levels) filters and
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
# Noise values in a camera's pool beyond one frame's: the number of distinct frame offsets.
NOISE_POOL_EXTRA = 1 << 20
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


@functools.lru_cache(maxsize=8)
def _raw_footprint(sensor: SensorSettings) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray]:
    """The raw pixels that see the warped image: their bounding box and warped coordinates.

    Returns
    -------
    box : (slice, slice)
        Rows and columns of the raw frame holding every pixel within one warped
        pixel of the warped image.
    map_x, map_y : ndarray, float32, the box's shape
        Warped (x, y) of each raw pixel centre in the box, for ``cv2.remap``.
    """
    w, h = sensor.warped_width_px, sensor.warped_height_px
    to_raw = np.linalg.inv(raw_to_warped_matrix(sensor))
    reach = np.array([[[-1.0, -1.0]], [[w, -1.0]], [[-1.0, h]], [[w, h]]])
    corners = cv2.perspectiveTransform(reach, to_raw)[:, 0]
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    x1 = min(int(np.ceil(corners[:, 0].max())) + 1, sensor.raw_width_px)
    y1 = min(int(np.ceil(corners[:, 1].max())) + 1, sensor.raw_height_px)
    xs, ys = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    warped = cv2.perspectiveTransform(np.dstack([xs, ys]), raw_to_warped_matrix(sensor)).astype(np.float32)
    return ((slice(y0, y1), slice(x0, x1)), _read_only(np.ascontiguousarray(warped[..., 0])),
            _read_only(np.ascontiguousarray(warped[..., 1])))


def _sample(field: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a warped-image ``field`` at raw pixels; zero beyond the field."""
    return cv2.remap(field, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)


@functools.lru_cache(maxsize=8)
def _raw_gain(sensor: SensorSettings) -> np.ndarray:
    """:func:`_channel_gain` seen by the raw pixels of :func:`_raw_footprint`'s box; 0 off the pad."""
    _, map_x, map_y = _raw_footprint(sensor)
    return _read_only(_sample(_channel_gain(sensor), map_x, map_y))


@functools.lru_cache(maxsize=8)
def _raw_marker_coverage(sensor: SensorSettings) -> np.ndarray:
    """:func:`_marker_pattern` at rest seen by the raw pixels of the footprint box."""
    _, map_x, map_y = _raw_footprint(sensor)
    return _read_only(_sample(_marker_pattern(sensor), map_x, map_y))


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

    def __init__(self, camera: TactileCamera, heights: np.ndarray, shears: np.ndarray | None,
                 used: np.ndarray) -> None:
        sensor = camera.sensor
        padded_heights = {k: camera._padded(heights[k]) for k in used}
        padded_shears = {} if shears is None or not sensor.markers else {
            k: camera._padded(shears[k]) for k in used}
        moved = np.zeros((sensor.warped_height_px, sensor.warped_width_px), bool)
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
        (fy, fx), foot_x, foot_y = _raw_footprint(sensor)
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
            self.slope_x[k] = _sample(cv2.sepFilter2D(height, cv2.CV_32F, derivative, smooth),
                                      window_x, window_y)
            self.slope_y[k] = _sample(cv2.sepFilter2D(height, cv2.CV_32F, smooth, derivative),
                                      window_x, window_y)
            if self.back_x is not None:
                shear = padded_shears[k][window]
                self.back_x[k] = _sample(np.ascontiguousarray(shear[..., 0]) * to_px, window_x, window_y)
                self.back_y[k] = _sample(np.ascontiguousarray(shear[..., 1]) * to_px, window_x, window_y)
            elif sensor.markers:
                self.height[k] = _sample(height, window_x, window_y)


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

    ``TactileCamera(sensor, ...)`` builds the camera of ``sensor.optics``: this
    Wedge model for ``"wedge"``, a
    :class:`~teleop.sim.table_optics.TableCamera` (same interface, the measured
    colour tables of a real sensor) otherwise.
    """

    def __new__(cls, *args, **kwargs):
        sensor = args[0] if args else kwargs.get("sensor")
        if cls is TactileCamera and getattr(sensor, "optics", "wedge") != "wedge":
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

        self._reflectance = _reflectance_map()
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
            box = _raw_footprint(sensor)[0]
            transmitted = 1.0 - MARKER_DARKNESS * _raw_marker_coverage(sensor)
            self._marked_f32 = self._background_f32.copy()  # before rounding: renders add a change to it
            self._marked_f32[box] *= cv2.merge([transmitted] * 3)
            self.rest_frame = _read_only(np.clip(np.rint(self._marked_f32), 0, 255).astype(np.uint8))
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
        c = self.sensor.crop_px
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
        coverage = _sample(self._marker_rest, cv2.add(series.map_x, back_x), cv2.add(series.map_y, back_y))
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
