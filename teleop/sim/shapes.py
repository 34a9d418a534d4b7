"""Object geometry for the grasp simulator: what each finger's gel sees of the object.

World frame: x is the squeeze axis, from the left finger toward the right one;
y and z span the pads (y along the left sensor's image columns, z up, against
its image rows). The object sits between the fingers at ``offset_m`` = (y, z)
from the pads' centres; its orientation is a rotation from its body frame.

Body frames (``ObjectSpec.size_m`` gives the extents along the body axes):

* sphere: diameter on every axis.
* cylinder: (diameter, diameter, length), axis along body z.
* box: edges (x, y, z), edges rounded by a small radius as real boxes are.
* hex_prism: (across flats, across corners, length): flats face body +-x, axis along z.
* irregular: a non-convex, non-axisymmetric blob: a superellipsoid with these
  extents whose radius is modulated by random lobes and dents (fixed per
  object name).

Each surface is a signed distance function (negative inside), ray-cast along
world x by sphere tracing and refined by bisection, vectorised over the
rays of the contact solver's grid. Surface texture (roughness) is a Gaussian
random field added to each finger's profile.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.spatial.transform import Rotation

from teleop.catalogue import ObjectSpec
from teleop.errors import SimulationError
from teleop.sim.contact import NO_CONTACT_GAP_M

__all__ = [
    "Pose",
    "Scene",
    "draw_pose",
    "make_scene",
    "narrowest_width",
    "object_size",
    "object_texture",
    "scaled_size",
    "surface_distance",
]

# Plausible sizes (m) when the catalogue gives none: log-uniform ranges per body axis.
SIZE_RANGES_M = {
    "sphere": ((0.015, 0.07),),
    "cylinder": ((0.008, 0.06), (0.02, 0.15)),  # diameter, length
    "box": ((0.015, 0.075), (0.015, 0.075), (0.015, 0.075)),
    "hex_prism": ((0.008, 0.04), (0.005, 0.06)),  # across flats, length
    "irregular": ((0.012, 0.07), (0.012, 0.07), (0.012, 0.07)),
}
# Typical roughness amplitude (m, RMS) by material, used when the catalogue says 0 (unknown).
TEXTURE_BY_MATERIAL_M = {
    "metal": 2e-6, "glass": 0.5e-6, "ceramic": 3e-6, "plastic": 5e-6, "rubber": 10e-6,
    "wood": 20e-6, "paper": 20e-6, "food": 30e-6, "foam": 100e-6,
}
DEFAULT_TEXTURE_M = 10e-6
TEXTURE_CORRELATION_M = 0.6e-3
# Edges of boxes, prisms and cylinder ends are rounded with this radius (capped by the size).
EDGE_RADIUS_M = 1.0e-3
# Objects must fit between the open fingers with this margin.
FIT_MARGIN = 0.95
# Pose draws: a small tilt always; flat faces sometimes meet the gel tilted onto an edge.
TILT_SD_RAD = math.radians(1.0)
EDGE_TILT_PROBABILITY = 0.25
EDGE_TILT_RANGE_RAD = (math.radians(2.0), math.radians(6.0))
END_ON_PROBABILITY = 0.25
OFFSET_FRACTION = 0.2  # contact point offset, as a fraction of the pad size
# Sphere tracing.
_TRACE_ITERATIONS = 160
_TRACE_HIT_M = 2e-7
_BRACKET_M = 2e-5  # bisection bracket around the traced hit (grazing rays stop short of the surface)
_BISECTIONS = 26


def _name_rng(name: str, purpose: str) -> np.random.Generator:
    """A generator fixed by the object's name (stable across runs and machines)."""
    digest = hashlib.blake2b(f"{purpose}:{name}".encode(), digest_size=8).digest()
    return np.random.default_rng(int.from_bytes(digest, "little"))


def object_size(obj: ObjectSpec) -> tuple[float, float, float]:
    """Extents (m) along the body axes: the catalogue's, or drawn from the name when unknown."""
    if obj.size_m is not None:
        return tuple(float(s) for s in obj.size_m)
    rng = _name_rng(obj.name, "size")
    draws = [math.exp(rng.uniform(math.log(lo), math.log(hi))) for lo, hi in SIZE_RANGES_M[obj.shape]]
    if obj.shape == "sphere":
        return (draws[0],) * 3
    if obj.shape == "cylinder":
        return (draws[0], draws[0], draws[1])
    if obj.shape == "hex_prism":
        return (draws[0], draws[0] * 2.0 / math.sqrt(3.0), draws[1])
    return tuple(draws)


def object_texture(obj: ObjectSpec) -> float:
    """Roughness amplitude (m, RMS): the catalogue's, or typical for the material when it says 0."""
    if obj.texture_m > 0:
        return obj.texture_m
    return TEXTURE_BY_MATERIAL_M.get(obj.material, DEFAULT_TEXTURE_M)


# --------------------------------------------------------------------------- surfaces


def _sd_sphere(q: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    return np.linalg.norm(q, axis=-1) - size[0] / 2


def _sd_round_box(q: np.ndarray, half: np.ndarray, radius: float) -> np.ndarray:
    d = np.abs(q) - (half - radius)
    return (np.linalg.norm(np.maximum(d, 0.0), axis=-1) + np.minimum(d.max(axis=-1), 0.0)) - radius


def _sd_capped(d_radial: np.ndarray, d_axial: np.ndarray, radius: float) -> np.ndarray:
    """Distance from a 2-D (radial, axial) offset to a rounded profile."""
    outside = np.hypot(np.maximum(d_radial, 0.0), np.maximum(d_axial, 0.0))
    return outside + np.minimum(np.maximum(d_radial, d_axial), 0.0) - radius


def _edge_radius(size: tuple[float, float, float]) -> float:
    return min(EDGE_RADIUS_M, 0.15 * min(size))


def _sd_cylinder(q: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    r = _edge_radius(size)
    radial = np.hypot(q[..., 0], q[..., 1]) - (size[0] / 2 - r)
    axial = np.abs(q[..., 2]) - (size[2] / 2 - r)
    return _sd_capped(radial, axial, r)


def _sd_box(q: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    return _sd_round_box(q, np.asarray(size) / 2, _edge_radius(size))


def _sd_hex_prism(q: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    """Hexagonal prism, flats facing body +-x (Quilez's exact distance, rounded)."""
    r = _edge_radius(size)
    apothem = size[0] / 2 - r
    kx, ky, kz = -math.sqrt(3.0) / 2, 0.5, 1.0 / math.sqrt(3.0)
    # In the hexagon's own 2-D frame the flats face +-v; body x maps to v.
    u, v = np.abs(q[..., 1]), np.abs(q[..., 0])
    fold = 2.0 * np.minimum(kx * u + ky * v, 0.0)
    u, v = u - fold * kx, v - fold * ky
    radial = np.hypot(u - np.clip(u, -kz * apothem, kz * apothem), v - apothem) * np.sign(v - apothem)
    axial = np.abs(q[..., 2]) - (size[2] / 2 - r)
    return _sd_capped(radial, axial, r)


def _irregular_radius(obj: ObjectSpec, size: tuple[float, float, float]) -> Callable[[np.ndarray], np.ndarray]:
    """Radius (m) of the irregular body along unit directions (..., 3): a superellipsoid with
    these extents, modulated by random lobes and dents fixed by the object's name."""
    rng = _name_rng(obj.name, "irregular")
    semi = np.asarray(size) / 2
    exponent = rng.uniform(2.0, 3.5)
    n_lobes = int(rng.integers(3, 7))
    centres = rng.normal(size=(n_lobes, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    amplitudes = rng.uniform(-0.2, 0.25, n_lobes)
    amplitudes[:2] = rng.uniform(-0.3, -0.15, 2)  # at least two dents: the body is not convex
    widths = rng.uniform(0.35, 0.6, n_lobes)

    def radius(unit: np.ndarray) -> np.ndarray:
        base = np.sum(np.abs(unit / semi) ** exponent, axis=-1) ** (-1.0 / exponent)
        lobes = np.exp(-(1.0 - unit @ centres.T) / widths**2) @ amplitudes
        return base * (1.0 + lobes) / (1.0 + max(amplitudes.max(), 0.0))  # stays within size

    return radius


def _irregular(obj: ObjectSpec, size: tuple[float, float, float]) -> Callable[[np.ndarray], np.ndarray]:
    """Star-shaped, so inside means |q| < rho(q / |q|); the returned function is
    (|q| - rho) scaled down so that it never exceeds the true distance for the
    slopes these lobes have (a safe step for sphere tracing)."""
    radius = _irregular_radius(obj, size)

    def distance(q: np.ndarray) -> np.ndarray:
        norm = np.linalg.norm(q, axis=-1)
        unit = q / np.maximum(norm, 1e-12)[..., None]
        return 0.45 * (norm - radius(unit))

    return distance


def _directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=-1)


def _hull_points(obj: ObjectSpec, size: tuple[float, float, float]) -> np.ndarray:
    """Body-frame points whose extent along any direction is the object's (to a fraction of a millimetre)."""
    if obj.shape == "sphere":
        return _directions(400) * (size[0] / 2)
    if obj.shape == "irregular":
        directions = _directions(2000)
        return directions * _irregular_radius(obj, size)(directions)[:, None]
    if obj.shape == "box":
        return np.array(np.meshgrid(*[(-s / 2, s / 2) for s in size])).reshape(3, -1).T
    angles = np.radians(np.arange(30.0, 360.0, 60.0) if obj.shape == "hex_prism" else np.arange(0.0, 360.0, 2.0))
    radius = size[0] / 2 / (np.cos(np.radians(30.0)) if obj.shape == "hex_prism" else 1.0)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=-1)
    return np.concatenate([np.column_stack([ring, np.full(len(ring), z)]) for z in (-size[2] / 2, size[2] / 2)])


def narrowest_width(obj: ObjectSpec, size: tuple[float, float, float]) -> float:
    """The object's smallest extent (m) over the body axes and 256 other directions."""
    directions = np.concatenate([np.eye(3), _directions(256)])
    return float(np.ptp(_hull_points(obj, size) @ directions.T, axis=0).min())


def scaled_size(obj: ObjectSpec, size: tuple[float, float, float], factors: tuple[float, float, float], *,
                max_width_m: float) -> tuple[float, float, float]:
    """``size`` (m, body axes) scaled by ``factors`` as far as the shape and the gripper allow.

    A sphere takes the first factor on every axis; a cylinder's or hex prism's
    cross-section the first on both of its axes (it stays round, or regular) and its
    length the third; a box or irregular body one factor per axis. A result whose
    narrowest width exceeds both the object's own and ``FIT_MARGIN``^2 x
    ``max_width_m`` (the pose draw's margin, twice: room for the pose's tilt) is
    shrunk as a whole to the larger of the two, so that an object that fits the
    gripper still fits it.
    """
    fx, fy, fz = factors
    if obj.shape == "sphere":
        scaled = tuple(s * fx for s in size)
    elif obj.shape in ("cylinder", "hex_prism"):
        scaled = (size[0] * fx, size[1] * fx, size[2] * fz)
    else:
        scaled = (size[0] * fx, size[1] * fy, size[2] * fz)
    bound = max(narrowest_width(obj, size), FIT_MARGIN**2 * max_width_m)
    width = narrowest_width(obj, scaled)
    return scaled if width <= bound else tuple(s * bound / width for s in scaled)


def surface_distance(obj: ObjectSpec, size: tuple[float, float, float]) -> Callable[[np.ndarray], np.ndarray]:
    """Signed distance (m, negative inside) to the object's surface at body-frame points (..., 3).

    For ``irregular`` a lower bound of the distance with the same sign.
    """
    if obj.shape == "irregular":
        return _irregular(obj, size)
    sd = {"sphere": _sd_sphere, "cylinder": _sd_cylinder, "box": _sd_box, "hex_prism": _sd_hex_prism}[obj.shape]
    return lambda q: sd(q, size)


# --------------------------------------------------------------------------- poses


@dataclass(frozen=True)
class Pose:
    """How the object is held: body-to-world rotation and its centre's offset (y, z) in the pad plane (m)."""

    rotation: np.ndarray
    offset_m: tuple[float, float]


def _axis_to(axis: int, target: int) -> Rotation:
    """A proper rotation taking body ``axis`` onto world ``target`` (0, 1, 2 = x, y, z)."""
    if axis == target:
        return Rotation.identity()
    other = 3 - axis - target
    vector = np.zeros(3)
    vector[other] = math.pi / 2
    rotation = Rotation.from_rotvec(vector)
    if not np.allclose(rotation.apply(np.eye(3)[axis]), np.eye(3)[target]):
        rotation = Rotation.from_rotvec(-vector)
    return rotation




def draw_pose(obj: ObjectSpec, size: tuple[float, float, float], *, rng: np.random.Generator,
              max_width_m: float, pad_m: tuple[float, float]) -> Pose:
    """Draw a grasp pose: the object re-oriented between grasps as on the rig.

    Cylinders and prisms lie side-on at a random angle in the pad plane, or
    stand end-on (flat punch) when short enough; boxes present a face that fits
    the gripper, sometimes tilted onto an edge; irregular objects and spheres
    take any orientation. The contact point is offset within the central part
    of the pad. Raises SimulationError when no orientation fits between the
    open fingers.
    """
    limit = FIT_MARGIN * max_width_m
    hull = _hull_points(obj, size)
    for _ in range(64):
        flat_face = obj.shape in ("box", "hex_prism")
        if obj.shape in ("sphere", "irregular"):
            base = Rotation.random(random_state=rng)
        elif obj.shape in ("cylinder", "hex_prism"):
            spin = Rotation.from_rotvec([0.0, 0.0, rng.uniform(0.0, 2.0 * math.pi)])  # about its own axis
            end_on = size[2] < limit and rng.random() < END_ON_PROBABILITY
            flat_face = flat_face or end_on
            base = _axis_to(2, 0 if end_on else 1) * spin
        else:
            fitting = [axis for axis in range(3) if size[axis] < limit]
            axis = int(rng.choice(fitting)) if fitting else 0
            base = _axis_to(axis, 0)
        tilt_size = (rng.uniform(*EDGE_TILT_RANGE_RAD) if flat_face and rng.random() < EDGE_TILT_PROBABILITY
                     else abs(rng.normal(0.0, TILT_SD_RAD)))
        tilt_direction = rng.uniform(0.0, 2.0 * math.pi)
        tilt = Rotation.from_rotvec([0.0, tilt_size * math.cos(tilt_direction), tilt_size * math.sin(tilt_direction)])
        in_plane = Rotation.from_rotvec([rng.uniform(0.0, 2.0 * math.pi), 0.0, 0.0])
        rotation = (in_plane * tilt * base).as_matrix()
        if np.ptp(hull @ rotation[0]) < limit:  # extent along the squeeze axis
            offset = tuple(float(rng.uniform(-OFFSET_FRACTION, OFFSET_FRACTION) * extent)
                           for extent in (pad_m[1], pad_m[0]))  # (y: pad width, z: pad height)
            return Pose(rotation=rotation, offset_m=offset)
    raise SimulationError(
        f"object {obj.name!r} ({obj.shape}, size {tuple(round(s, 4) for s in size)} m, "
        f"{narrowest_width(obj, size):.3g} m across at its narrowest) does not fit between fingers open to "
        f"{max_width_m} m in any orientation drawn: a grasp needs it under {FIT_MARGIN:g} x {max_width_m:g} = "
        f"{limit:.4g} m along the squeeze, tilt included"
    )


# --------------------------------------------------------------------------- ray casting


def _trace(distance: Callable[[np.ndarray], np.ndarray], origins: np.ndarray, direction: np.ndarray,
           length: float) -> np.ndarray:
    """Distance along ``direction`` from each origin to the first surface crossing (NaN: none)."""
    t = np.zeros(origins.shape[0])
    live = np.arange(origins.shape[0])
    hit = np.zeros(origins.shape[0], dtype=bool)
    for _ in range(_TRACE_ITERATIONS):
        if live.size == 0:
            break
        d = distance(origins[live] + t[live, None] * direction)
        arrived = d < _TRACE_HIT_M
        hit[live[arrived]] = True
        t[live] += np.where(arrived, 0.0, np.maximum(d, _TRACE_HIT_M))
        live = live[~arrived & (t[live] < length)]
    # Refine the crossing by bisection between just before and the reached point.
    idx = np.flatnonzero(hit)
    lo = np.maximum(t[idx] - 4 * _TRACE_HIT_M, 0.0)  # the traced segment is outside the body
    hi = t[idx] + _BRACKET_M
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        inside = distance(origins[idx] + mid[:, None] * direction) < 0
        hi = np.where(inside, mid, hi)
        lo = np.where(inside, lo, mid)
    out = np.full(origins.shape[0], np.nan)
    out[idx] = 0.5 * (lo + hi)
    return out


def _cast(obj: ObjectSpec, size: tuple[float, float, float], pose: Pose, y: np.ndarray, z: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """World x of the object's surface first met from -x and from +x along rays at (y, z); NaN: miss."""
    distance = surface_distance(obj, size)
    bound = 0.5 * float(np.linalg.norm(size)) + 1e-3
    inverse = pose.rotation.T  # world -> body
    points = np.stack([np.full(y.size, -bound), y.ravel() - pose.offset_m[0], z.ravel() - pose.offset_m[1]], axis=-1)
    forward = _trace(distance, points @ inverse.T, inverse[:, 0], 2 * bound)
    points[:, 0] = bound
    backward = _trace(distance, points @ inverse.T, -inverse[:, 0], 2 * bound)
    return (forward - bound).reshape(y.shape), (bound - backward).reshape(y.shape)


@dataclass(frozen=True)
class Scene:
    """What the grasp simulator needs of one object in one pose.

    Attributes
    ----------
    gap_m : dict of finger -> ndarray (rows, cols)
        Gap (m, >= 0, min 0) between each finger's undeformed gel and the object
        on the contact grid, in that sensor's image orientation;
        :data:`~teleop.sim.contact.NO_CONTACT_GAP_M` where the object does not
        face the pad.
    extent_m : float
        Distance along the squeeze axis between the two first-contact points:
        the fingers touch the object when their gels are this far apart.
    cross_section_m2 : float
        Mean cross-section normal to the squeeze axis (volume / extent), for
        the object's bulk compression.
    first_contact_rc : dict of finger -> (row, col)
        Grid cell of first contact.
    """

    gap_m: dict[str, np.ndarray]
    extent_m: float
    cross_section_m2: float
    first_contact_rc: dict[str, tuple[int, int]]


def _texture(shape: tuple[int, int], cell_m: tuple[float, float], amplitude_m: float,
             rng: np.random.Generator) -> np.ndarray:
    field = gaussian_filter(rng.standard_normal(shape), sigma=[TEXTURE_CORRELATION_M / c for c in cell_m],
                            mode="wrap")
    return field * (amplitude_m / max(float(field.std()), 1e-30))


def make_scene(obj: ObjectSpec, pose: Pose, *, shape: tuple[int, int], cell_m: tuple[float, float],
               fingers: tuple[str, str], rng: np.random.Generator,
               size: tuple[float, float, float] | None = None) -> Scene:
    """Ray-cast the object between two pads and build each finger's gap profile.

    Parameters
    ----------
    obj : ObjectSpec
    pose : Pose
    shape, cell_m : grid (rows, cols) and cell size (row, col pitch, m) of the contact solver,
        centred on the pad.
    fingers : (left, right)
        Names of the finger at -x and at +x. The right sensor sees the pad
        mirrored (its image columns run along -y).
    rng : Generator
        Draws the surface texture.
    size : extents, optional
        Defaults to :func:`object_size`.

    Raises
    ------
    SimulationError
        The object misses both pads in this pose.
    """
    size = object_size(obj) if size is None else size
    rows, cols = shape
    v = (np.arange(rows) - (rows - 1) / 2) * cell_m[0]
    u = (np.arange(cols) - (cols - 1) / 2) * cell_m[1]
    uu, vv = np.meshgrid(u, v)
    left_x, right_x = _cast(obj, size, pose, uu, -vv)  # image rows run down, world z up
    hit = np.isfinite(left_x) & np.isfinite(right_x)
    if not hit.any():
        raise SimulationError(f"object {obj.name!r} does not face the pads in this pose (offset {pose.offset_m} m)")
    amplitude = object_texture(obj)
    left_surface = np.where(hit, left_x - _texture(shape, cell_m, amplitude, rng), np.nan)
    right_surface = np.where(hit, right_x + _texture(shape, cell_m, amplitude, rng), np.nan)
    left_min, right_max = np.nanmin(left_surface), np.nanmax(right_surface)
    gaps = {
        fingers[0]: np.where(hit, left_surface - left_min, NO_CONTACT_GAP_M),
        fingers[1]: np.fliplr(np.where(hit, right_max - right_surface, NO_CONTACT_GAP_M)),
    }
    extent = float(right_max - left_min)

    # Volume from a coarse cast over the whole object (it may be larger than the pads).
    reach = 0.5 * float(np.linalg.norm(size))
    coarse = np.linspace(-reach, reach, 28)
    cy, cz = np.meshgrid(coarse + pose.offset_m[0], coarse + pose.offset_m[1])
    front, back = _cast(obj, size, pose, cy, cz)
    thickness = np.nan_to_num(back - front, nan=0.0)
    volume = float(thickness.sum() * (coarse[1] - coarse[0]) ** 2)
    global_extent = float(np.nanmax(back) - np.nanmin(front))
    return Scene(
        gap_m=gaps,
        extent_m=extent,
        cross_section_m2=volume / global_extent,
        first_contact_rc={f: tuple(int(i) for i in np.unravel_index(np.argmin(g), g.shape)) for f, g in gaps.items()},
    )
