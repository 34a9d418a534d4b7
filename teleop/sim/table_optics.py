"""Tactile optics from a real sensor's measured colour tables: gel height map in, raw frame out.

The Wedge optics (:mod:`teleop.sim.wedge_optics`) is an appearance model with made-up
lights. This module renders through what was *measured* on two real sensors,
a GelSight R1.5 and a GelSight Mini, as the ``taxim`` package ships them
(``taxim/calib/gelsight/`` and ``taxim/calib/gelsight_mini/``; Si and Yuan,
*Taxim*, IEEE RA-L 2022). Only those data files are read; the package is
located without being imported (importing it pulls in torch or jax).

Frames
------
As in :mod:`teleop.sim.camera_geometry`: heights arrive on the sensor's *grid* (the image
the estimator sees, ``sensor.image_shape``, x right, y down, pixels of
``sensor.pixel_pitch_m``), frames leave as the *raw* camera image. These sensors
look straight at the gel (no mirror): ``model = "mini"`` renders the raw frame as the
grid, or a ``"wedge"`` model's settings give the identity warp (``warp_corners_px``
at the raw corners, warped size = raw size) and a small ``crop_px``, though any warp
works (:func:`~teleop.sim.camera_geometry.pad_view`). The tables are in raw pixels of the
recording, so the raw frame must have the recording's size (``params.json``:
480 x 640 for both).

Table model
-----------
``polycalib.npz`` holds, per colour channel, a table of 125 x 125 gradient bins.
A pixel's surface gradient g = (dz/dx, dz/dy) (z toward the camera, i.e. the
gel's indentation ``h``; x, y in the same unit) is binned by its magnitude,
arctan|g| in [0, pi/2], and its direction, atan2(dz/dy, dz/dx) in [-pi, pi], each
axis cut into 124 equal bins. Each bin holds the 6 coefficients of a quadratic
in the pixel's raw position (x, y) px that gives the colour change (8-bit
levels) against the no-contact frame::

    dI = c0 x^2 + c1 y^2 + c2 x y + c3 x + c4 y + c5

so the change follows both the slope and where on the pad it is (the light
falls differently across the pad). ``grad_r``, ``grad_g``, ``grad_b`` are the
B, G, R channels of the recorded (OpenCV, BGR) frames: the names follow the
channel index, as taxim's own loader notes.

Rendering: the height is blurred by the sensor's ``deform_final_sigma``
(``params.json``, 2 raw px) and differentiated as in the Wedge optics; each raw
pixel looks up the coefficients at its gradient, interpolated bilinearly
between bin centres (taxim takes the bin's value as is; interpolating removes
the steps of up to ~2 levels between neighbouring direction bins; ``cv2.remap``
resolves 1/32 of a bin), and evaluates the quadratic at its own position. The table is used *relative to a flat gel*
(bin 0 is subtracted), so an untouched gel renders exactly the recorded
no-contact frame ``f0`` of ``dataPack.npz``, which is the background; the
change is scaled by ``sim.illumination_gain``. For speed the coefficients are
rescaled once to positions normalised to [0, 1) and stored as six 4-channel
tables, one per term, each looked up with one ``cv2.remap``.

What is left out: the gel's rest shape (``gelmap.npy``; the simulator's
mechanics treat the gel as a flat layer and ``f0`` already shows the gel at
rest), taxim's pyramid blur that fakes the gel sinking in around a contact
(the contact mechanics give the real displacement) and its shadow table.
Camera noise, markers, the windowing to where the gel moved and the mixing of
basis surfaces are :class:`~teleop.sim.optics.OpticsRenderer`'s.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from teleop.errors import SimulationError
from teleop.settings import SensorSettings, SimulationSettings, resolve_path
from teleop.sim.camera_geometry import pad_view, read_only
from teleop.sim.optics import OpticsRenderer, load_background
from teleop.sim.wedge_optics import REFLECTANCE_STEP

__all__ = [
    "SensorTables",
    "TableCamera",
    "calibration_dir",
    "colour_change",
    "feature_planes",
    "load_tables",
    "lookup_tables",
]

#: ``SensorSettings.optics`` -> folder under ``taxim/calib``.
OPTICS_FOLDERS = {"gelsight": "gelsight", "gelsight_mini": "gelsight_mini"}
TERMS = 6  # x^2, y^2, xy, x, y, 1


def calibration_dir(optics: str) -> Path:
    """The folder of ``optics``'s measured tables in the installed ``taxim`` package.

    Raises
    ------
    SimulationError
        ``optics`` has no tables, or ``taxim`` is not installed.
    """
    if optics not in OPTICS_FOLDERS:
        raise SimulationError(f"optics {optics!r} has no measured tables: expected one of {sorted(OPTICS_FOLDERS)}")
    spec = importlib.util.find_spec("taxim")  # locate, never import: taxim imports torch or jax
    if spec is None or not spec.submodule_search_locations:
        raise SimulationError(f"optics {optics!r} reads the real sensor's tables from the `taxim` package, which "
                              "is not installed: pip install taxim (its data only; no torch or jax needed)")
    return Path(next(iter(spec.submodule_search_locations))) / "calib" / OPTICS_FOLDERS[optics]


@dataclass(frozen=True)
class SensorTables:
    """One real sensor's measured optics, as recorded.

    Attributes
    ----------
    name : str
        The ``SensorSettings.optics`` value.
    polynomials : ndarray, float64, shape (bins, bins, 3, 6)
        [magnitude bin, direction bin, BGR channel, term]: coefficients of the
        colour change (levels) in raw px (x, y), terms x^2, y^2, xy, x, y, 1.
    background : ndarray, uint8, shape (H, W, 3)
        The recorded no-contact frame ``f0`` (BGR).
    pixel_pitch_m : float
        Gel surface per raw pixel (``params.json`` "pixmm").
    blur_px : float
        Gaussian blur of the height (raw px), taxim's ``deform_final_sigma``.
    """

    name: str
    polynomials: np.ndarray
    background: np.ndarray
    pixel_pitch_m: float
    blur_px: float

    @property
    def raw_shape(self) -> tuple[int, int]:
        """(rows, cols) of the recorded frames, px."""
        return self.background.shape[:2]

    @property
    def bins(self) -> int:
        """Bins per gradient axis (125)."""
        return self.polynomials.shape[0]


@functools.lru_cache(maxsize=4)
def load_tables(optics: str) -> SensorTables:
    """Read ``optics``'s tables (``polycalib.npz``, ``params.json``, ``f0`` of ``dataPack.npz``).

    Raises
    ------
    SimulationError
        A file is missing or malformed.
    """
    folder = calibration_dir(optics)
    try:
        params = json.loads((folder / "params.json").read_text())
        sensor, sim = params["sensor"], params["simulator"]
        bins, pixmm, sigma_x, sigma_y = sensor["num_bins"], sensor["pixmm"], *sim["deform_final_sigma_rel"]
        with np.load(folder / "polycalib.npz") as poly:
            channels = [np.asarray(poly[name], dtype=np.float64) for name in ("grad_r", "grad_g", "grad_b")]
        with np.load(folder / "dataPack.npz") as pack:
            f0 = np.ascontiguousarray(pack["f0"])
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise SimulationError(f"cannot read the {optics!r} optics tables in {folder}: {exc!r}") from exc
    polynomials = np.stack(channels, axis=2)
    if polynomials.shape != (bins, bins, 3, TERMS) or (bins - 1) % 2:
        raise SimulationError(f"{folder / 'polycalib.npz'}: tables of shape {channels[0].shape}: expected "
                              f"({bins}, {bins}, {TERMS}) with an even number of bin intervals")
    if f0.shape != (sensor["h"], sensor["w"], 3) or f0.dtype != np.uint8:
        raise SimulationError(f"{folder / 'dataPack.npz'}: f0 is {f0.dtype} {f0.shape}: expected uint8 "
                              f"({sensor['h']}, {sensor['w']}, 3)")
    blur = 0.5 * (sigma_x * sensor["w"] + sigma_y * sensor["h"])  # sigmas relative to the width, height
    return SensorTables(name=optics, polynomials=read_only(polynomials), background=read_only(f0),
                        pixel_pitch_m=float(pixmm) * 1e-3, blur_px=float(blur))


@functools.lru_cache(maxsize=8)
def lookup_tables(optics: str, gain: float = 1.0) -> np.ndarray:
    """``optics``'s tables arranged for :func:`colour_change`, float32 (6, bins, bins + 1, 4).

    Entry [k, m, 1 + j, c] is ``gain`` times term k's coefficient of channel c
    (BGR; c = 3 is zero padding for 4-channel remaps) for positions normalised
    to u = x / W, v = y / H, minus the flat gel's (magnitude bin 0, same
    direction bin), at magnitude bin m and direction bin j. Columns 0 and
    ``bins`` repeat the last and the first direction bin, so a bilinear lookup
    wraps around (direction bin ``bins - 1`` holds only +pi, which is -pi).
    """
    tables = load_tables(optics)
    rows, cols = tables.raw_shape
    relative = tables.polynomials - tables.polynomials[:1]
    relative = relative * np.array([cols**2, rows**2, rows * cols, cols, rows, 1.0]) * gain
    n = tables.bins - 1
    wrapped = np.concatenate([relative[:, n - 1:n], relative[:, :n], relative[:, :1]], axis=1)
    out = np.zeros((TERMS, tables.bins, n + 2, 4), dtype=np.float32)
    out[..., :3] = wrapped.transpose(3, 0, 1, 2)
    return read_only(out)


@functools.lru_cache(maxsize=4)
def feature_planes(shape: tuple[int, int]) -> np.ndarray:
    """Terms u^2, v^2, u v, u, v of each raw pixel, u = x / W, v = y / H, each repeated in 4
    channels (to multiply 4-channel lookups); float32 (5, H, W, 4)."""
    rows, cols = shape
    v, u = np.meshgrid(np.arange(rows) / rows, np.arange(cols) / cols, indexing="ij")
    terms = np.stack([u * u, v * v, u * v, u, v]).astype(np.float32)
    return read_only(np.ascontiguousarray(np.repeat(terms[..., None], 4, axis=-1)))


def colour_change(lookup: np.ndarray, features: np.ndarray, slope_x: np.ndarray, slope_y: np.ndarray,
                  *, slope_unit: float = 1.0) -> np.ndarray:
    """BGR colour change (8-bit levels) of pixels whose surface has the given slopes.

    Parameters
    ----------
    lookup : ndarray
        :func:`lookup_tables`.
    features : ndarray, float32, shape (5, h, w, 4)
        :func:`feature_planes` at the pixels.
    slope_x, slope_y : ndarray, float32, shape (h, w)
        dz/dx and dz/dy (z toward the camera; x right, y down), in units of
        ``slope_unit``.

    Returns
    -------
    ndarray, float32, shape (h, w, 3)
        Zero where both slopes are zero.
    """
    n_mag, n_dir = lookup.shape[1], lookup.shape[2] - 2
    # Table coordinates, bin centres at i + 1/2: magnitude from 0 (a flat gel: bin 0, replicated
    # below its centre), direction from -pi, shifted by the wrapped column in front. (numpy's
    # arctan2, not cv2.phase: that one is accurate to 0.3 degrees, a tenth of a bin.)
    mag_coord = np.arctan(cv2.magnitude(slope_x, slope_y) * np.float32(slope_unit))
    mag_coord *= np.float32((n_mag - 1) / (0.5 * math.pi))
    mag_coord -= np.float32(0.5)
    dir_coord = np.arctan2(slope_y, slope_x)
    dir_coord += np.float32(math.pi)
    dir_coord *= np.float32(n_dir / (2.0 * math.pi))
    dir_coord += np.float32(0.5)
    total = cv2.remap(lookup[TERMS - 1], dir_coord, mag_coord, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    term = np.empty_like(total)
    for k in range(TERMS - 1):
        cv2.remap(lookup[k], dir_coord, mag_coord, cv2.INTER_LINEAR, dst=term, borderMode=cv2.BORDER_REPLICATE)
        cv2.accumulateProduct(term, features[k], total)
    return cv2.cvtColor(total, cv2.COLOR_BGRA2BGR)


class TableCamera(OpticsRenderer):
    """A simulated camera of a real GelSight-type sensor, rendered through its measured tables.

    Same interface and behaviour as :class:`~teleop.sim.optics.OpticsRenderer`
    (``render``, ``render_series``, ``capture``, ``capture_series``,
    ``add_noise``, ``background``, ``rest_frame``; camera noise and markers
    alike); only the shading differs (module notes). ``OpticsRenderer(sensor,
    ...)`` builds one for a sensor whose ``optics`` is not ``"wedge"``.

    Parameters
    ----------
    sensor : SensorSettings
        ``optics`` names the real sensor; its raw frame must be the recording's
        size (480 x 640).
    sim : SimulationSettings
        ``camera_noise``, ``jpeg_quality``, ``illumination_gain``; a non-empty
        ``background`` replaces the recorded no-contact frame.
    rng : numpy.random.Generator
        Source of camera noise.
    background : ndarray, optional
        Raw uint8 BGR no-contact frame; default: ``sim.background`` if set, else
        the real sensor's recorded ``f0``.

    Raises
    ------
    SimulationError
        The optics has no tables, ``taxim`` is missing, or the raw size differs
        from the recording's.
    """

    def __init__(self, sensor: SensorSettings, *, sim: SimulationSettings,
                 rng: np.random.Generator, background: np.ndarray | None = None) -> None:
        tables = load_tables(sensor.optics)
        raw_shape = (sensor.raw_height_px, sensor.raw_width_px)
        if raw_shape != tables.raw_shape:
            raise SimulationError(
                f"sensor {sensor.finger!r} has a {raw_shape[1]}x{raw_shape[0]} px raw frame: the {sensor.optics!r} "
                f"tables were measured on {tables.raw_shape[1]}x{tables.raw_shape[0]} px frames")
        if background is None:
            if sim.background:
                background = load_background(resolve_path(sim.background))
            else:
                background = tables.background
        super().__init__(sensor, sim=sim, rng=rng, background=background)
        # Slopes in the Wedge's reflectance-map units (the marker flow relies on them), with no
        # offset; the height is blurred by the real sensor's blur, from raw to warped px.
        blur = tables.blur_px * pad_view(sensor).width_px / sensor.raw_width_px
        gaussian = cv2.getGaussianKernel(2 * math.ceil(4 * blur) + 1, blur)[:, 0]
        to_slope = 1.0 / (sensor.pixel_pitch_m * REFLECTANCE_STEP)
        self._slope_kernels = (
            np.convolve(gaussian, [0.25, 0.5, 0.25]).astype(np.float32),
            (to_slope * np.convolve(gaussian, [-0.5, 0.0, 0.5])).astype(np.float32),
        )
        self._map_origin = 0.0
        self._lookup = lookup_tables(sensor.optics, float(sim.illumination_gain))
        self._features = feature_planes(raw_shape)

    def _shade(self, series, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
        rows, cols = series.box
        return colour_change(self._lookup, self._features[:, rows, cols], map_x, map_y, slope_unit=REFLECTANCE_STEP)
