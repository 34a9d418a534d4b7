"""Analytical estimators of Young's modulus from one grasp's loading series.

Every estimator fits a line by least squares over the loading frames, turns
the slope's interval into an interval on the object's compliance and maps
that to an :class:`~estimator.estimate.Estimate` with an explicit state:
a compliance interval that reaches zero means the object is stiffer than the
data resolve (a lower bound), one that is unbounded above means it is softer
than they resolve (an upper bound), both at once is a refusal. No path
returns a NaN, negative or infinite modulus.

Inputs (1-D, one value per loading frame, in time order; SI units):

``force_n``
    Normal force (N), load-cell baseline removed.
``approach_m``
    Per-finger approach since the contact onset: half the decrease of the
    fingertip separation, i.e. the gripper width corrected for finger
    compliance (:func:`approach_per_finger`).
``depth_m``
    Peak gel indentation (m).
``area_m2``, ``contact_radius_m``
    Contact area (m^2) and radius (m) measured on the tactile image.

Intervals (about 95 % for what they include) combine the fit's residual scatter (Student t on its
degrees of freedom) with the measurement resolution propagated through the
fit (:class:`~estimator.linefit.MeasurementNoise`: force noise, width noise, depth resolution,
pixel pitch, and two errors shared by all frames: the depth reconstruction's
scale uncertainty and the fingertip separation at the contact onset), so that
even a fit through exact points reports the resolution it rests on. Fits
through at least 3 points have an intercept, so an error in the onset (where
approach and strain are zero) shifts the line without tilting it; with 1 or 2
points they pass through the onset instead, and carry its uncertainty.
They leave out the error of the contact mechanics each fit assumes, often the larger one, so
they hold less often than 95 %: `estimator evaluate` reports how often for each method (the
model card's tables). Only a learned model's intervals are calibrated to a level.

The depth-based methods refuse a series whose gel indentation falls while
the approach grows (beyond the depth noise): the sign of a contact wider
than the pad, whose depth the border-anchored reconstruction cannot see, or
of a slipping object.

Contact mechanics follow the brief, not the printed paper: compliance
``k = (1 - nu^2) / E``, ``1/E* = k_sensor + k_object``, the Hertz centre
displacement ``u(0) = k * pi * p0 * a / 2`` with ``p0 = 3 F / (2 pi a^2)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from estimator.errors import FitError
from estimator.estimate import Estimate
from estimator.fit_inputs import poisson_ratio, positive, real_array
from estimator.gel_layer import gel_layer_factor
from estimator.linefit import MeasurementNoise, fit_line, no_line_reason

__all__ = [
    "METHODS",
    "approach_per_finger",
    "elastic",
    "hertz",
    "no_tactile",
    "series",
]

METHODS = ("no_tactile", "elastic", "hertz", "series")

def approach_per_finger(
    width_m: np.ndarray,
    force_n: np.ndarray,
    *,
    onset_width_m: float,
    finger_stiffness_n_per_m: float,
) -> np.ndarray:
    """Per-finger approach since the contact onset (m).

    The gripper reports its width at the motor; under force ``F`` the
    fingertips bend open by ``F / finger_stiffness_n_per_m``, so the fingertip
    separation is ``width + F / k``. The approach is half its decrease from the
    width at onset (where the force is zero).
    """
    width = real_array("approach_per_finger", "width_m", width_m)
    tip = width + real_array("approach_per_finger", "force_n", force_n) / finger_stiffness_n_per_m
    return (onset_width_m - tip) / 2.0


# --------------------------------------------------------------------------- helpers


def _frames(method: str, **arrays: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Arrays as float64 1-D of one length, and the mask of frames where all are finite."""
    out = {name: real_array(method, name, a) for name, a in arrays.items()}
    lengths = {name: a.shape for name, a in out.items()}
    if any(a.ndim != 1 for a in out.values()) or len(set(lengths.values())) > 1:
        raise FitError(f"{method}: inputs must be 1-D series of one length, got shapes {lengths}")
    finite = np.logical_and.reduce([np.isfinite(a) for a in out.values()])
    return out, finite


def _poisson_factor(method: str, poisson: float) -> float:
    poisson_ratio(method, "object_poisson", poisson)
    return 1.0 - float(poisson) ** 2


def _modulus(method: str, k: float, k_lo: float, k_hi: float, *, factor: float, basis: str) -> Estimate:
    """Estimate from an object-compliance interval [k_lo, k_hi] (1/Pa; k_hi may be inf).

    ``factor`` turns compliance into modulus: ``E = factor / k`` (``1 - nu^2``
    for contact compliance, 1 for a uniaxial strain-per-stress).
    """
    if k_hi <= 0:
        resolution = (k_hi - k_lo) / 2.0
        state, values = "lower_bound", (factor / resolution if resolution > 0 else math.inf,)
        why = ("compliance below zero beyond the noise, so the object is stiffer than resolved; "
               "bound at the compliance resolution")
    elif k_lo <= 0 and math.isinf(k_hi):
        return Estimate.refuse(method, f"{basis}: neither a stiffness nor a softness limit is resolved")
    elif k_lo <= 0:
        state, values = "lower_bound", (factor / k_hi,)
        why = "the object's compliance is within the resolution of zero"
    elif math.isinf(k_hi):
        state, values = "upper_bound", (factor / k_lo,)
        why = "the object is softer than the data resolve"
    else:
        state, values = "ok", (factor / k, factor / k_hi, factor / k_lo)
        why = ""
    if not all(math.isfinite(v) and v > 0 for v in values):
        return Estimate.refuse(method, f"{basis}: the modulus is out of the representable range")
    reason = f"{basis}: {why}" if why else basis
    if state == "ok":
        return Estimate.ok(method, *values, reason)
    if state == "lower_bound":
        return Estimate.at_least(method, values[0], reason)
    return Estimate.at_most(method, values[0], reason)


def _safe(method: str, build: Callable[[], Estimate]) -> Estimate:
    """Run ``build``; numbers that overflow or vanish become a refusal saying so."""
    with np.errstate(all="ignore"):
        try:
            return build()
        except (ZeroDivisionError, OverflowError) as exc:
            return Estimate.refuse(method, f"the fit's numbers are out of range ({exc})")


def _falling_depth(approach: np.ndarray, depth: np.ndarray, noise: MeasurementNoise) -> str:
    """Why the depth series is unusable, or "": the gel's indentation cannot fall while the
    fingers close further (beyond the depth noise). It does when the contact is wider than the
    pad (the gradients the depth is built from leave the image), the object slips, or the frames
    are misaligned in time with the force and width (a camera clock offset: each frame is paired
    with another moment's approach, more so at high frame rates); the reason says whether the widths
    closed at all. Frames where either is not finite are ignored."""
    finite = np.isfinite(approach) & np.isfinite(depth)
    order = np.argsort(approach[finite], kind="stable")
    by_approach = depth[finite][order]
    with np.errstate(over="ignore"):  # a drop beyond the float range (inf) is a fall all the same
        drop = float(np.max(np.maximum.accumulate(by_approach) - by_approach, initial=0.0))
    if not drop > 3.0 * math.sqrt(2.0) * noise.depth_m + 1e-12:
        return ""
    fell = f"the gel's indentation falls by {drop * 1e3:.3g} mm"
    closing = approach[finite]  # in time order: how far the fingers closed over the loading
    moved = float(closing[-1] - closing[0])
    if abs(moved) <= 3.0 * noise.approach_m:
        return (f"{fell} while the widths show no approach over the loading (within their noise): the object "
                "slips, the contact is wider than the pad, or the width readings do not follow the grasp")
    if moved < 0:
        return (f"{fell} where the widths give more approach: they open by {-2e3 * moved:.3g} mm over the loading "
                "while the force rises, so the width readings do not follow the grasp, or the object slips")
    return (f"{fell} while the approach grows: the contact is likely wider than the pad, the object slips, or "
            "the frames are misaligned in time with the force and width (a camera timing offset, which "
            "`estimator estimate --camera-lag` estimates and corrects for the analytical methods)")


def _auto_origin(n: int) -> bool:
    return n < 3


# --------------------------------------------------------------------------- methods


def _uniaxial(
    method: str,
    stress_pa: np.ndarray,
    strain: np.ndarray,
    sigma_stress_pa: np.ndarray,
    sigma_strain: np.ndarray,
    *,
    what: str,
    systematic_strain: Sequence[np.ndarray] = (),
) -> Estimate:
    """Hooke's law: fit strain = C * stress (compliance C = 1/E), uniaxial, no Poisson factor."""
    origin = _auto_origin(stress_pa.size)
    first = fit_line(stress_pa, strain, sigma_strain, through_origin=origin)
    if first is None:
        why = no_line_reason(stress_pa, through_origin=origin, x_name="stress", y_name="strain")
        return Estimate.refuse(method, f"{what}: {why}")
    sigma = np.sqrt(sigma_strain**2 + (first.slope * sigma_stress_pa) ** 2)
    line = fit_line(stress_pa, strain, sigma, through_origin=origin, systematic_y=systematic_strain)
    if line is None:
        return Estimate.refuse(method, f"{what}: the fit is undetermined")
    basis = f"{what}: strain per stress " + line.describe("C")
    return _modulus(method, line.slope, line.low, line.high, factor=1.0, basis=basis)


def no_tactile(
    force_n: np.ndarray,
    approach_m: np.ndarray,
    *,
    initial_width_m: float,
    pad_area_m2: float,
    noise: MeasurementNoise = MeasurementNoise(),
) -> Estimate:
    """Hooke's law on force and width alone (paper eq. 1-3 with A = pad area, d = 0).

    Stress ``F / A_pad``; strain ``2 * approach / w0``, ``w0`` the fingertip
    separation at onset.

    Parameters
    ----------
    force_n, approach_m : ndarray, shape (n,)
        See the module docstring.
    initial_width_m : float
        Fingertip separation at the contact onset (m).
    pad_area_m2 : float
        Imaged gel area (m^2).
    noise : MeasurementNoise
    """
    method = "no_tactile"
    initial_width_m, pad_area_m2 = positive(method, initial_width_m=initial_width_m, pad_area_m2=pad_area_m2)
    s, ok = _frames(method, force_n=force_n, approach_m=approach_m)
    if not ok.any():
        return Estimate.refuse(method, "no loading sample with finite force and width")
    force, approach = s["force_n"][ok], s["approach_m"][ok]

    def build() -> Estimate:
        stress = force / pad_area_m2
        strain = 2.0 * approach / initial_width_m
        sigma_strain = np.full(strain.shape, 2.0 * noise.approach_m / initial_width_m)
        sigma_stress = np.full(stress.shape, noise.force_n / pad_area_m2)
        onset = np.full(strain.shape, 2.0 * noise.onset_approach_m / initial_width_m)
        return _uniaxial(method, stress, strain, sigma_stress, sigma_strain, what="Hooke on F, w",
                         systematic_strain=(onset,))

    return _safe(method, build)


def elastic(
    force_n: np.ndarray,
    approach_m: np.ndarray,
    depth_m: np.ndarray,
    area_m2: np.ndarray,
    *,
    initial_width_m: float,
    noise: MeasurementNoise = MeasurementNoise(),
    truncated: np.ndarray | None = None,
) -> Estimate:
    """Simple elasticity with the measured contact area and depth (paper eq. 1-3).

    Stress ``F / A``; the object's extent is the fingertip separation plus
    the gel indentation on both sides, so its strain since onset is
    ``2 * (approach - depth) / w0``. Frames without contact area are skipped.

    Parameters
    ----------
    force_n, approach_m, depth_m, area_m2 : ndarray, shape (n,)
        See the module docstring.
    initial_width_m : float
        Fingertip separation at the contact onset (m).
    noise : MeasurementNoise
    truncated : ndarray of bool, shape (n,), optional
        Frames whose contact reaches the pad edge (area underestimated). They
        are left out when others remain; an estimate resting on them alone
        overstates the stress, so it is reported as an upper bound.
    """
    method = "elastic"
    (initial_width_m,) = positive(method, initial_width_m=initial_width_m)
    s, ok = _frames(method, force_n=force_n, approach_m=approach_m, depth_m=depth_m, area_m2=area_m2)
    ok &= s["area_m2"] > 0
    if not ok.any():
        return Estimate.refuse(method, "no loading frame has a contact area above the threshold")
    if why := _falling_depth(s["approach_m"], s["depth_m"], noise):
        return Estimate.refuse(method, why)
    ok, only_truncated = _drop_truncated(ok, truncated, s["area_m2"].size)
    force, approach, depth, area = (s[k][ok] for k in ("force_n", "approach_m", "depth_m", "area_m2"))

    def build() -> Estimate:
        stress = force / area
        strain = 2.0 * (approach - depth) / initial_width_m
        sigma_strain = np.full(strain.shape, 2.0 * math.hypot(noise.approach_m, noise.depth_m) / initial_width_m)
        sigma_stress = noise.force_n / area
        depth_scale = 2.0 * noise.depth_scale * depth / initial_width_m
        onset = np.full(strain.shape, 2.0 * noise.onset_approach_m / initial_width_m)
        result = _uniaxial(method, stress, strain, sigma_stress, sigma_strain, what="σ = F/A, ε = 2(δ-d)/w0",
                           systematic_strain=(depth_scale, onset))
        if not only_truncated:
            return result
        note = "contact reaches the pad edge in every frame: area underestimated, E overstated"
        if result.state == "ok":
            return Estimate.at_most(method, result.interval_pa[1], f"{result.reason}; {note}")
        if result.state == "upper_bound":
            return result.with_note(note)
        return Estimate.refuse(method, f"{result.reason}; {note}")

    return _safe(method, build)


def _drop_truncated(ok: np.ndarray, truncated: np.ndarray | None, n: int) -> tuple[np.ndarray, bool]:
    """Leave out truncated frames when untruncated ones remain; say whether only truncated remain."""
    if truncated is None:
        return ok, False
    cut = np.asarray(truncated, dtype=bool)
    if cut.shape != (n,):
        raise FitError(f"truncated must have shape ({n},), got {cut.shape}")
    if (ok & ~cut).any():
        return ok & ~cut, False
    return ok, True


def hertz(
    force_n: np.ndarray,
    approach_m: np.ndarray,
    depth_m: np.ndarray,
    contact_radius_m: np.ndarray,
    *,
    gel_compliance_per_pa: float,
    object_poisson: float,
    noise: MeasurementNoise = MeasurementNoise(),
    truncated: np.ndarray | None = None,
) -> Estimate:
    """Hertz contact through MDR with the textbook centre displacement.

    The apparent sphere radius is ``R = a^2 / approach`` (Hertz: approach =
    a^2 / R; the paper's eq. 4 uses the full width change, twice the
    per-finger approach). The gel's centre displacement

        d = k_sensor * pi * p0 * a / 2 = k_sensor * a * (3 E*^2 F / (4 R^2))^(1/3)

    is linear in ``s = E*^(2/3)``; ``s`` is fitted through the origin, then
    ``k_object = 1/E* - k_sensor`` and ``E = (1 - nu_object^2) / k_object``.
    ``E*`` at or above the gel's own ``1 / k_sensor`` gives a lower bound.

    Parameters
    ----------
    force_n, approach_m, depth_m, contact_radius_m : ndarray, shape (n,)
        See the module docstring; frames where any is <= 0 are skipped.
    gel_compliance_per_pa : float
        ``(1 - nu_gel^2) / E_gel`` (1/Pa).
    object_poisson : float
    noise : MeasurementNoise
    truncated : ndarray of bool, shape (n,), optional
        Frames whose contact reaches the pad edge (radius underestimated,
        which understates E*). Left out when others remain; an estimate
        resting on them alone is reported as a lower bound.
    """
    method = "hertz"
    (gel_compliance_per_pa,) = positive(method, gel_compliance_per_pa=gel_compliance_per_pa)
    factor = _poisson_factor(method, object_poisson)
    s, ok = _frames(method, force_n=force_n, approach_m=approach_m, depth_m=depth_m,
                    contact_radius_m=contact_radius_m)
    ok &= (s["force_n"] > 0) & (s["approach_m"] > 0) & (s["depth_m"] > 0) & (s["contact_radius_m"] > 0)
    if not ok.any():
        return Estimate.refuse(method, "no loading frame with positive force, approach, depth and "
                                       "contact radius")
    ok, only_truncated = _drop_truncated(ok, truncated, s["force_n"].size)
    if why := _falling_depth(s["approach_m"], s["depth_m"], noise):
        return Estimate.refuse(method, why)
    force, approach, depth, radius = (s[k][ok] for k in ("force_n", "approach_m", "depth_m",
                                                         "contact_radius_m"))
    k_gel = gel_compliance_per_pa

    def build() -> Estimate:
        shape = k_gel * np.cbrt(0.75 * force) * np.cbrt(approach) ** 2 / np.cbrt(radius)
        relative = np.sqrt((noise.force_n / (3 * force)) ** 2
                           + (2 * noise.approach_m / (3 * approach)) ** 2
                           + (noise.length_m / 2 / (3 * radius)) ** 2)
        first = fit_line(shape, depth, np.full(depth.shape, noise.depth_m), through_origin=True)
        if first is None:
            return Estimate.refuse(method, "the Hertz fit is undetermined")
        sigma = np.sqrt(noise.depth_m**2 + (first.slope * shape * relative) ** 2)
        # The onset error shifts every approach alike, so every shape by (2/3) shape d_approach / approach.
        onset = first.slope * shape * 2.0 * noise.onset_approach_m / (3.0 * approach)
        line = fit_line(shape, depth, sigma, through_origin=True,
                        systematic_y=(noise.depth_scale * depth, onset))
        if line is None or line.high <= 0:
            return Estimate.refuse(method, "the Hertz fit gives no positive E*")
        e_star = max(line.slope, 0.0) ** 1.5
        e_star_lo = max(line.low, 0.0) ** 1.5
        e_star_hi = line.high**1.5
        k = 1.0 / e_star - k_gel if e_star > 0 else math.inf
        k_lo = 1.0 / e_star_hi - k_gel
        k_hi = 1.0 / e_star_lo - k_gel if e_star_lo > 0 else math.inf
        basis = (f"Hertz/MDR: E* = {e_star:.4g} Pa in [{e_star_lo:.3g}, {e_star_hi:.3g}] "
                 f"(gel alone 1/k = {1 / k_gel:.4g} Pa) from " + line.describe("E*^(2/3)"))
        result = _modulus(method, k, k_lo, k_hi, factor=factor, basis=basis)
        if not only_truncated:
            return result
        note = "contact reaches the pad edge in every frame: radius underestimated, E* understated"
        if result.state == "ok":
            return Estimate.at_least(method, result.interval_pa[0], f"{result.reason}; {note}")
        if result.state == "lower_bound":
            return result.with_note(note)
        return Estimate.refuse(method, f"{result.reason}; {note}")

    return _safe(method, build)


def series(
    approach_m: np.ndarray,
    depth_m: np.ndarray,
    *,
    gel_compliance_per_pa: float,
    object_poisson: float,
    noise: MeasurementNoise = MeasurementNoise(),
    contact_radius_m: np.ndarray | None = None,
    gel_thickness_m: float | None = None,
    gel_poisson: float | None = None,
    force_n: np.ndarray | None = None,
    initial_width_m: float | None = None,
) -> Estimate:
    """Series compliance: the gel's share of the approach at the first-contact point.

    The gel and the object are two compliances in series: both carry the same
    pressure, so at the first-contact point the object's displacement is
    ``k_object / k_sensor`` times what the gel would show if it were a
    half-space. The gel is a thin bonded layer, whose centre compliance is
    ``eta(a/h) k_sensor`` (:func:`~estimator.gel_layer.gel_layer_factor`, from the measured contact
    radius ``a``; ``eta = 1`` when no radius or thickness is given), so the
    per-finger approach is

        delta = d + k_object * (d / (eta k_sensor) + b F),

    with ``d`` the gel's indentation. ``b F`` is the object's bulk compression
    per finger, ``F w0 / (2 A E)``: its extent ``w0`` (the fingertip separation
    at onset) squeezed over a mean cross-section taken as a ball's of that
    diameter, ``A = pi w0^2 / 6`` (the object's depth and height are not
    seen), so ``b = 3 / (pi w0 (1 - nu^2))``; left out unless ``force_n`` and
    ``initial_width_m`` are given. ``k_object`` is the least-squares slope of
    ``delta - d`` on the bracket (with an intercept from 3 frames on, which
    absorbs an onset error); ``E = (1 - nu^2) / k_object``.

    States: a slope within noise of zero (``delta - d`` within the depth and
    width resolution: metal, glass) gives a lower bound at the slope's upper
    limit; an indentation that never leaves its noise (the gel barely moves
    against a very soft foam) gives an upper bound from the smallest
    compliance consistent with the depth resolution.

    Parameters
    ----------
    approach_m, depth_m : ndarray, shape (n,)
        See the module docstring.
    gel_compliance_per_pa : float
        ``(1 - nu_gel^2) / E_gel`` (1/Pa).
    object_poisson : float
    noise : MeasurementNoise
    contact_radius_m : ndarray, shape (n,), optional
        Hertz contact radius per frame (m), for the layer factor.
    gel_thickness_m, gel_poisson : float, optional
        The gel layer (needed with ``contact_radius_m``).
    force_n : ndarray, shape (n,), optional
        Force per frame (N), for the bulk compression.
    initial_width_m : float, optional
        Fingertip separation at onset (m), for the bulk compression.
    """
    method = "series"
    (gel_compliance_per_pa,) = positive(method, gel_compliance_per_pa=gel_compliance_per_pa)
    factor = _poisson_factor(method, object_poisson)
    n = np.size(approach_m)
    layered = contact_radius_m is not None and gel_thickness_m is not None and gel_poisson is not None
    bulk = force_n is not None and initial_width_m is not None
    s, ok = _frames(method, approach_m=approach_m, depth_m=depth_m,
                    contact_radius_m=contact_radius_m if layered else np.zeros(n),
                    force_n=force_n if bulk else np.zeros(n))
    if not ok.any():
        return Estimate.refuse(method, "no loading frame with finite approach and depth")
    approach, depth = s["approach_m"][ok], s["depth_m"][ok]
    if why := _falling_depth(approach, depth, noise):
        return Estimate.refuse(method, why)
    k_gel = gel_compliance_per_pa
    if bulk:
        (initial_width_m,) = positive(method, initial_width_m=initial_width_m)
        bulk_per_pa = 3.0 * np.maximum(s["force_n"][ok], 0.0) / (math.pi * initial_width_m * factor)
    else:
        bulk_per_pa = np.zeros(depth.shape)
    model = ("layered gel" if layered else "half-space gel") + (" + bulk" if bulk else "")

    def build() -> Estimate:
        # Inside _safe: a radius far beyond any gel (a / h overflows) ends in a refusal, not a warning.
        eta = (gel_layer_factor(np.maximum(s["contact_radius_m"][ok], 0.0), gel_thickness_m=gel_thickness_m,
                                gel_poisson=gel_poisson) if layered else np.ones(depth.shape))
        if not np.all(eta > 0):
            return Estimate.refuse(method, "a contact radius is out of range for the gel layer (a / h overflows)")
        lever = depth / (eta * k_gel) + bulk_per_pa  # object displacement per unit k_object (Pa)
        gap = approach - depth
        sigma_gap = math.hypot(noise.approach_m, noise.depth_m)
        if float(np.max(depth)) <= 3.0 * noise.depth_m:
            # The gel barely moves: the object is at least as compliant as the depth resolution allows.
            lever_hi = float(np.max(3.0 * noise.depth_m / (eta * k_gel) + bulk_per_pa))
            k_lo = (float(np.max(gap)) - 2.0 * sigma_gap) / lever_hi
            if not k_lo > 0:
                return Estimate.refuse(method, f"series compliance ({model}): neither the gel nor the "
                                               "object moves beyond the resolution")
            return _modulus(method, math.inf, k_lo, math.inf, factor=factor,
                            basis=f"series compliance ({model}): the gel's indentation "
                                  f"{float(np.max(depth)) * 1e3:.3g} mm stays within its noise")
        origin = _auto_origin(depth.size)
        share = fit_line(approach, depth, np.full(depth.shape, sigma_gap), through_origin=origin)
        if share is not None and share.high <= 0:
            return Estimate.refuse(method, f"series compliance ({model}): the gel's indentation does "
                                           "not grow with the approach")
        first = fit_line(lever, gap, np.full(gap.shape, sigma_gap), through_origin=origin)
        if first is None:
            return Estimate.refuse(method, no_line_reason(lever, through_origin=origin, x_name="gel's indentation",
                                                          y_name="approach less the gel's indentation"))
        sigma_lever = noise.depth_m / (eta * k_gel)
        sigma = np.sqrt(sigma_gap**2 + (first.slope * sigma_lever) ** 2)
        # A depth scale error moves d in the gap and in the lever together.
        depth_scale = noise.depth_scale * depth * (1.0 + max(first.slope, 0.0) / (eta * k_gel))
        onset = np.full(gap.shape, noise.onset_approach_m)  # the approach's onset error, in every gap
        line = fit_line(lever, gap, sigma, through_origin=origin, systematic_y=(depth_scale, onset))
        if line is None:
            return Estimate.refuse(method, "the series fit is undetermined")
        basis = f"series compliance ({model}): " + line.describe("k_object")
        return _modulus(method, line.slope, line.low, line.high, factor=factor, basis=basis)

    return _safe(method, build)
