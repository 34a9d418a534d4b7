"""The analytic optics of a simulated GelSight Wedge: its lights, its pad, its empty frame.

The camera looks at the gel from behind, so an indentation ``h`` (m, into the gel)
moves the membrane toward the camera: the surface seen is z = h(x, y). Three
grazing coloured lights shine across the membrane as in the Wedge: green from the
left, red from the top, blue from the bottom, each at ``LIGHT_ELEVATION_RAD`` above
the gel. Each light's relative change of Lambertian radiance (plus a weak Phong
highlight) is computed from the surface normal (:func:`reflectance_map`, tabulated
once over surface slopes), scaled by that light's irradiance across the pad (a
smooth, uneven gain field, fixed per sensor: :func:`channel_gain`), mixed into BGR
by the LEDs' colour signatures; :class:`~teleop.sim.optics.OpticsRenderer` scales
it by ``sim.illumination_gain`` and adds it to the raw no-contact background.

:func:`procedural_background` draws a Wedge-like raw no-contact frame when no
recorded one is configured. The gain fields are on the warped image
(:func:`~teleop.sim.camera_geometry.pad_view`); all of it is deterministic per sensor, and the
cached arrays are read-only.
"""

from __future__ import annotations

import functools
import zlib

import cv2
import numpy as np

from teleop.settings import SensorSettings
from teleop.sim.camera_geometry import pad_view, read_only, warped_coordinates

__all__ = [
    "REFLECTANCE_STEP",
    "SLOPE_LIMIT",
    "channel_gain",
    "procedural_background",
    "reflectance_map",
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
# Lens blur of the procedural background (raw px).
LENS_BLUR_PX = 0.8


def _sensor_seed(sensor: SensorSettings) -> int:
    """A stable seed per physical sensor: its illumination does not change between grasps."""
    return zlib.crc32(f"{sensor.model}/{sensor.finger}/{sensor.serial}".encode())


def _smooth_gain(sensor: SensorSettings, *, amplitude: float) -> np.ndarray:
    """A smooth multiplicative field 1 +- ``amplitude`` across the warped image, fixed per sensor."""
    knots = np.random.default_rng(_sensor_seed(sensor)).uniform(-1.0, 1.0, (4, 5)).astype(np.float32)
    view = pad_view(sensor)
    field = cv2.resize(knots, (view.width_px, view.height_px), interpolation=cv2.INTER_CUBIC)
    return 1.0 + amplitude * np.clip(field, -1.0, 1.0)


def _vignette(sensor: SensorSettings) -> np.ndarray:
    """Radial fall-off of the whole pad's brightness (1 at the centre), float32 (H, W)."""
    x, y = warped_coordinates(sensor)
    view = pad_view(sensor)
    u = 2.0 * x / (view.width_px - 1) - 1.0
    v = 2.0 * y / (view.height_px - 1) - 1.0
    return (1.0 - 0.32 * u**2 - 0.12 * v**2).astype(np.float32)


def _edge_distances(sensor: SensorSettings) -> np.ndarray:
    """Distance (warped px) from the edge each light enters by: left, top, bottom. (3, H, W)."""
    x, y = warped_coordinates(sensor)
    return np.stack([x, y, pad_view(sensor).height_px - 1 - y])


@functools.lru_cache(maxsize=8)
def channel_gain(sensor: SensorSettings) -> np.ndarray:
    """Shading gain (levels per unit relative radiance change) per BGR channel, float32 (H, W, 3).

    Each light fades away from its edge (grazing light loses intensity across the
    pad), scaled by the sensor's fixed uneven-illumination field and the vignette.
    Each colour channel takes the field of the light that dominates it (the LEDs'
    small leaks into other channels follow that field too, which saves a colour
    transform per frame).
    """
    view = pad_view(sensor)
    extent = np.array([view.width_px, view.height_px, view.height_px], dtype=np.float32)[:, None, None]
    fade = 0.6 + 0.4 * np.exp(-_edge_distances(sensor) / (0.5 * extent))
    irradiance = fade * _smooth_gain(sensor, amplitude=0.08) * _vignette(sensor)
    dominant = np.argmax(LIGHT_BGR, axis=1)
    gain = SHADING_GAIN_LEVELS * irradiance[dominant].transpose(1, 2, 0)
    return read_only(np.ascontiguousarray(gain, dtype=np.float32))


@functools.cache
def reflectance_map() -> np.ndarray:
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
    return read_only(cv2.transform(np.stack(per_light, axis=-1).astype(np.float32), LIGHT_BGR))


@functools.lru_cache(maxsize=8)
def _lit_housing(sensor: SensorSettings) -> np.ndarray:
    """The deterministic part of :func:`procedural_background`, float32 raw BGR, lens-blurred."""
    view = pad_view(sensor)
    ww, wh = view.width_px, view.height_px
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
    to_raw = np.linalg.inv(view.raw_to_warped)
    pad_raw = cv2.warpPerspective(pad, to_raw, size, flags=cv2.INTER_LINEAR)
    inside = cv2.warpPerspective(np.ones((wh, ww), np.float32), to_raw, size, flags=cv2.INTER_LINEAR)

    # Dark housing, a little brighter toward the bottom, and the second mirror view to the right.
    depth = np.linspace(0.0, 1.0, sensor.raw_height_px, dtype=np.float32)[:, None, None]
    frame = np.array([8.0, 8.0, 4.0], np.float32) + np.array([20.0, 9.0, 7.0], np.float32) * depth**2
    frame = np.broadcast_to(frame, (sensor.raw_height_px, sensor.raw_width_px, 3)).copy()
    if view.mirrored:  # a flat sensor has no mirror (and its corners are not read)
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
    return read_only(cv2.GaussianBlur(frame, (0, 0), LENS_BLUR_PX))  # softens the pad's border


def procedural_background(sensor: SensorSettings, *, rng: np.random.Generator) -> np.ndarray:
    """A Wedge-like raw no-contact frame, uint8 BGR (raw_height_px, raw_width_px, 3).

    The pad (the raw footprint of the warped image; a flat sensor's whole frame) is a bright bluish-grey with
    a vignette, a green glow along its left edge, red along the top and blue
    along the bottom, as in the real Wedge frames; the sensor's uneven
    illumination is fixed per sensor (seeded from its model, finger and serial).
    Around the pad the frame is dark, with the dim second mirror view at the
    right. ``rng`` only scatters dust specks over the gel.
    """
    # Dust specks: single bright pixels on the gel, spread by the lens blur.
    n_specks = int(rng.integers(8, 20))
    view = pad_view(sensor)
    on_gel = np.column_stack([rng.uniform(0, view.width_px, n_specks), rng.uniform(0, view.height_px, n_specks)])
    raw_xy = cv2.perspectiveTransform(on_gel[:, None], np.linalg.inv(view.raw_to_warped))[:, 0]
    cols = np.clip(np.rint(raw_xy[:, 0]).astype(int), 0, sensor.raw_width_px - 1)
    rows = np.clip(np.rint(raw_xy[:, 1]).astype(int), 0, sensor.raw_height_px - 1)
    specks = np.zeros((sensor.raw_height_px, sensor.raw_width_px), np.float32)
    np.add.at(specks, (rows, cols), rng.uniform(60.0, 140.0, n_specks).astype(np.float32))
    frame = _lit_housing(sensor) + cv2.GaussianBlur(specks, (0, 0), LENS_BLUR_PX)[..., None]
    return np.clip(np.rint(frame), 0, 255).astype(np.uint8)
