"""How ``estimator evaluate`` scores estimates against labels: the per-method metrics.

A scored row (:func:`estimator.evaluation.evaluate.result_row`) holds one method's estimate of
one labelled grasp: ``state``, ``e_pa``, ``low_pa``, ``high_pa`` and the label
``truth_pa``, ``material`` and ``shape``. Refusals (``insufficient_data``) are
missing: left out of every figure but ``states`` and ``soft_refused`` (of ``n``, the errors and
shares, ``rigid_shown_rigid``, the coverage and the width medians). An estimate the display shows
as unknown (``shown_unknown``) is counted: left out only of the felt figures and the dangerous
misses, it stays in ``rigid_shown_rigid`` as not rigid and in the width medians at the width of
the display's whole range. So the felt figures are over the placed estimates (``n`` minus
``shown_unknown``), every other share over the ``n`` counted ones.

Per method :func:`summarise` gives

``n``
    estimates that count (every state but ``insufficient_data``);
``log10_error``
    mean ``|log10 E_hat - log10 E|`` over them (a bound counts with its bound
    value);
``within_10x``
    share of them with ``|log10 E_hat - log10 E| <= 1``;
``point_log10_error``, ``point_within_10x``
    the same with a documented point value for each bound (:func:`point_value`):
    the geometric middle of the bound and the physical limit on that side
    (:data:`E_MAX_PA` = 1e12 Pa above diamond for a lower bound, :data:`E_MIN_PA`
    = 1e3 Pa below the softest gels and foams for an upper bound); an ``ok``
    estimate counts with ``E_pa``;
``ok_only``
    ``n``, ``log10_error`` and ``within_10x`` over the ``ok`` estimates alone;
``felt_log10_error``
    mean ``|log10 E_felt - log10 clip(E)|``: ``E_felt`` is the modulus the
    softness display renders for the estimate (:func:`felt_pa`: the display's own
    :func:`~haptics.mapping.map_estimate`, its stiffness fraction turned back into
    a modulus), ``clip(E)`` the label clipped to the display's range
    ``[e_soft_pa, e_rigid_pa]``: what the operator feels against the best the
    display could have rendered; over the estimates the display places (an estimate whose
    interval spans its whole range it shows as unknown, as a refusal:
    :func:`~haptics.mapping.map_estimate`);
``shown_unknown``
    how many counted estimates the display shows as unknown, left out of the felt figures
    and the dangerous misses (not of ``rigid_shown_rigid``: a rigid object shown unknown is
    not shown rigid);
``felt_within_2x``
    share with that felt error ``<= log10(2)`` (:data:`FELT_WITHIN_FACTOR`), plus 1e-9 decade of
    slack: a rendered modulus goes through the display's log scale and back, and float rounding
    must not turn one rendered at exactly 2x into a miss;
``dangerous_misses``
    how many a person would misjudge badly (:func:`dangerous_miss`): a rigid object
    (label ``>=`` :data:`RIGID_TRUTH_PA` = 100 MPa) felt below the lower of
    :data:`RIGID_FELT_BELOW_PA` = 1 MPa and the display's rigid end, or a soft one (label
    ``<=`` :data:`SOFT_TRUTH_PA` = 1 MPa) felt at or above the lower of
    :data:`SOFT_FELT_FROM_PA` = 10 MPa and the display's rigid end: ``E_felt < min(1 MPa,
    e_rigid_pa)`` or ``E_felt >= min(10 MPa, e_rigid_pa)``. A display whose rigid end is
    below 10 MPa (the default: the sensor's resolution limit, about 6.8 MPa) cannot render
    10 MPa, so there the soft miss is a soft object rendered at the rigid end;
``rigid_shown_rigid``
    share of the counted rigid objects' grasps (label ``>=`` :data:`RIGID_TRUTH_PA`;
    refusals left out, one shown unknown counted as not rigid) the display renders rigid (its
    rigid flag: at the rigid end); None when there are none;
``interval_level``
    the nominal coverage the method states for its intervals (a learned model's,
    from its metadata; None for the analytical methods and for old models);
``interval_coverage``
    share whose interval (open side included) contains the label;
``interval_width_decades_median``
    median width in decades of the interval as the display shows it, over the counted
    estimates (:func:`~haptics.mapping.interval_decades` as :func:`~haptics.mapping.map_estimate`
    reads the estimate: clipped to the display's range, an open side reaching the
    range's end; one shown unknown at the width of the whole range; refusals left out);
``soft_n``, ``soft_felt_log10_error``, ``soft_felt_within_2x``, ``soft_interval_coverage``, ``soft_interval_width_decades_median``
    the counted grasps, felt error, share felt within 2x, interval coverage and median
    width over the objects at or below :data:`SOFT_SUBSET_MAX_PA` = 3 MPa: the objects
    the display can scale (its rigid end is the sensor's resolution limit, about 6.8 MPa),
    where rigid objects rendered rigid at zero error do not hide the misses (None when
    there are none). As overall: refusals left out of all of them, the felt figures over
    the placed ones (``soft_n`` minus those shown unknown);
``soft_refused``
    how many of those objects' grasps the method refused (not in ``soft_n``): the soft
    figures rest on ``soft_n`` of ``soft_n + soft_refused`` grasps;
``states``
    how many of each state, refusals included (the only figure besides ``soft_refused`` that
    counts them);
``per_material``, ``per_shape``
    the same metrics (all but ``interval_level``) per label material and shape;
``paper``
    the paper's figure on unseen real objects for the method (:data:`PAPER`; its
    ablation table), None where the paper has none.

The felt and width figures need the display's range (``display_range_pa``); without
it they are None.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from estimator.estimate import STATES
from haptics.mapping import EstimateUpdate, Percept, map_estimate, modulus_from_fraction
from teleop.physics import (  # the physical limits a bound's point value is taken against
    E_MAX_PA,
    E_MIN_PA,
)

__all__ = [
    "E_MAX_PA",
    "E_MIN_PA",
    "FELT_WITHIN_FACTOR",
    "PAPER",
    "RIGID_FELT_BELOW_PA",
    "RIGID_TRUTH_PA",
    "SOFT_FELT_FROM_PA",
    "SOFT_SUBSET_MAX_PA",
    "SOFT_TRUTH_PA",
    "dangerous_miss",
    "felt_log10_error",
    "felt_log10_offset",
    "felt_pa",
    "felt_within",
    "point_value",
    "summarise",
]


#: The felt figure counts a grasp as right when rendered within this factor of the clipped label.
FELT_WITHIN_FACTOR = 2.0
#: A label at or above this (Pa) is a rigid object (wood, plastics, metals)...
RIGID_TRUTH_PA = 1e8
#: ...and rendering one below this (Pa; or below the display's rigid end, when lower) is a dangerous miss.
RIGID_FELT_BELOW_PA = 1e6
#: A label at or below this (Pa) is a soft object (foams, gels, soft rubbers)...
SOFT_TRUTH_PA = 1e6
#: ...and rendering one at or above this (Pa; or at the display's rigid end, when lower) is a dangerous miss.
SOFT_FELT_FROM_PA = 1e7
#: The soft objects' figures: labels at or below this (Pa), the objects the display can scale.
SOFT_SUBSET_MAX_PA = 3e6

# Float slack for the within-2x share: a rendered value goes through the log scale and back, and
# one rendered at exactly 2x must not read as a miss by rounding.
_TOLERANCE_DECADES = 1e-9

# The paper's unseen-object figures (ablation table): mean |log10 error| and share within one
# decade, keyed by method, and for a learned one by ``method[variant]`` (its inputs).
PAPER: dict[str, dict[str, float] | None] = {
    "no_tactile": {"log10_error": 2.13, "within_10x": 0.182},
    "elastic": {"log10_error": 1.90, "within_10x": 0.273},
    "hertz": {"log10_error": 1.68, "within_10x": 0.289},
    "series": None,
    "hybrid[rgb+markers+fw+analytical]": {"log10_error": 0.76, "within_10x": 0.735},
    "hybrid[rgb+markers+analytical]": {"log10_error": 0.76, "within_10x": 0.742},
    "hybrid[rgb+fw+analytical]": {"log10_error": 0.88, "within_10x": 0.686},
    "hybrid[rgb+analytical]": {"log10_error": 0.90, "within_10x": 0.679},
    "cnn[rgb+markers+fw]": {"log10_error": 0.86, "within_10x": 0.646},
    "cnn[rgb+markers]": {"log10_error": 0.85, "within_10x": 0.650},
    "hybrid[depth+fw+analytical]": {"log10_error": 0.98, "within_10x": 0.636},
    "hybrid[depth+analytical]": {"log10_error": 1.04, "within_10x": 0.594},
}


def point_value(state: str, e_pa: float) -> float:
    """The value a bound counts with in the point metrics: the geometric middle of the bound and
    the physical limit on its open side (``e_pa`` itself for ``ok`` or a bound beyond the limit)."""
    if state == "lower_bound" and e_pa < E_MAX_PA:
        return math.sqrt(e_pa * E_MAX_PA)
    if state == "upper_bound" and e_pa > E_MIN_PA:
        return math.sqrt(e_pa * E_MIN_PA)
    return e_pa


def _rendered(row: Mapping[str, Any], display_range_pa: tuple[float, float]) -> tuple[Percept, float]:
    """What the display renders for a scored row: its percept and the modulus that stands for."""
    soft, rigid = display_range_pa
    update = EstimateUpdate(e_pa=row["e_pa"], interval_pa=(row["low_pa"], row["high_pa"]), state=row["state"])
    percept = map_estimate(update, e_soft_pa=soft, e_rigid_pa=rigid)
    return percept, modulus_from_fraction(percept.stiffness, e_soft_pa=soft, e_rigid_pa=rigid)


def felt_pa(row: Mapping[str, Any], *, display_range_pa: tuple[float, float]) -> float | None:
    """The modulus (Pa) the softness display renders for a scored row's estimate.

    The display's own mapping (:func:`~haptics.mapping.map_estimate`) gives the stiffness
    fraction of its range; :func:`~haptics.mapping.modulus_from_fraction` turns it back into a
    modulus (exact: the scale is logarithmic), so the value lies in ``display_range_pa``.

    Parameters
    ----------
    row : mapping
        A scored row with ``state``, ``e_pa``, ``low_pa`` and ``high_pa``.
    display_range_pa : (float, float)
        The display's ``(e_soft_pa, e_rigid_pa)``.

    Returns
    -------
    float or None
        None for a refusal (``insufficient_data``) and an estimate the display shows as unknown
        (its interval spans the display's whole range): the display renders nothing.
    """
    if row["state"] == "insufficient_data":
        return None
    percept, felt = _rendered(row, display_range_pa)
    return None if percept.unknown else felt


def felt_log10_offset(felt: float, truth_pa: float, *, display_range_pa: tuple[float, float]) -> float:
    """Decades from the label clipped to the display's range (the best the display could have
    rendered: an object stiffer than its rigid end is right when rendered rigid) to a rendered
    modulus ``felt``: negative when the object was felt softer than it is."""
    soft, rigid = display_range_pa
    return math.log10(felt) - math.log10(min(rigid, max(soft, truth_pa)))


def felt_log10_error(felt: float, truth_pa: float, *, display_range_pa: tuple[float, float]) -> float:
    """How far (decades) a rendered modulus ``felt`` lies from the label clipped to the display's
    range: the size of :func:`felt_log10_offset`."""
    return abs(felt_log10_offset(felt, truth_pa, display_range_pa=display_range_pa))


def felt_within(error_decades: float) -> bool:
    """Whether a felt error counts as right: within :data:`FELT_WITHIN_FACTOR` of the clipped label."""
    return error_decades <= math.log10(FELT_WITHIN_FACTOR) + _TOLERANCE_DECADES


def dangerous_miss(truth_pa: float, felt: float, *, e_rigid_pa: float) -> bool:
    """Whether rendering ``felt`` (Pa) for an object of modulus ``truth_pa`` is a dangerous miss.

    A rigid object (``truth_pa >= RIGID_TRUTH_PA``) felt below the lower of 1 MPa and the
    display's rigid end (``min(RIGID_FELT_BELOW_PA, e_rigid_pa)``), or a soft one (``truth_pa <=
    SOFT_TRUTH_PA``) felt at or above the lower of 10 MPa and the display's rigid end
    (``min(SOFT_FELT_FROM_PA, e_rigid_pa)``): on a display whose rigid end is below 10 MPa, a
    soft object rendered at the rigid end.
    """
    if truth_pa >= RIGID_TRUTH_PA and felt < min(RIGID_FELT_BELOW_PA, e_rigid_pa):
        return True
    return truth_pa <= SOFT_TRUTH_PA and felt >= min(SOFT_FELT_FROM_PA, e_rigid_pa)


def _log_errors(rows: Sequence[dict[str, Any]], value: Callable[[dict[str, Any]], float]) -> list[float]:
    return [abs(math.log10(value(r)) - math.log10(r["truth_pa"])) for r in rows]


def _summary(errors: Sequence[float]) -> tuple[float | None, float | None]:
    if not errors:
        return None, None
    return sum(errors) / len(errors), sum(e <= 1.0 for e in errors) / len(errors)


def _median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def _felt_metrics(counted: Sequence[dict[str, Any]], display_range_pa: tuple[float, float] | None) -> dict[str, Any]:
    """The display's figures over the counted rows (module docstring); None without a range."""
    if display_range_pa is None:
        return dict.fromkeys(("felt_log10_error", "felt_within_2x", "dangerous_misses", "shown_unknown",
                              "rigid_shown_rigid", "interval_width_decades_median", "soft_felt_log10_error",
                              "soft_felt_within_2x", "soft_interval_width_decades_median"))
    rigid = display_range_pa[1]
    errors, soft_errors, misses, unknown, widths, soft_widths, rigid_shown = [], [], 0, 0, [], [], []
    for r in counted:
        percept, felt = _rendered(r, display_range_pa)
        if r["truth_pa"] >= RIGID_TRUTH_PA:
            rigid_shown.append(percept.rigid)
        widths.append(percept.uncertainty_decades)
        if _soft(r):
            soft_widths.append(percept.uncertainty_decades)
        if percept.unknown:
            unknown += 1
            continue
        errors.append(felt_log10_error(felt, r["truth_pa"], display_range_pa=display_range_pa))
        misses += dangerous_miss(r["truth_pa"], felt, e_rigid_pa=rigid)
        if _soft(r):
            soft_errors.append(errors[-1])
    return {
        "felt_log10_error": _mean(errors),
        "felt_within_2x": _within_2x(errors),
        "dangerous_misses": misses,
        "shown_unknown": unknown,
        "rigid_shown_rigid": sum(rigid_shown) / len(rigid_shown) if rigid_shown else None,
        "interval_width_decades_median": _median(widths),
        "soft_felt_log10_error": _mean(soft_errors),
        "soft_felt_within_2x": _within_2x(soft_errors),
        "soft_interval_width_decades_median": _median(soft_widths),
    }


def _soft(row: Mapping[str, Any]) -> bool:
    return row["truth_pa"] <= SOFT_SUBSET_MAX_PA


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _within_2x(felt_errors: Sequence[float]) -> float | None:
    return sum(map(felt_within, felt_errors)) / len(felt_errors) if felt_errors else None


def _metrics(rows: Iterable[dict[str, Any]], *,
             display_range_pa: tuple[float, float] | None = None) -> dict[str, Any]:
    """The metrics of one group of rows (module docstring); the felt and width figures are None
    without ``display_range_pa``."""
    rows = list(rows)
    counted = [r for r in rows if r["state"] != "insufficient_data"]
    errors = _log_errors(counted, lambda r: r["e_pa"])
    point_error, point_within = _summary(_log_errors(counted, lambda r: point_value(r["state"], r["e_pa"])))
    ok = [r for r in counted if r["state"] == "ok"]
    ok_error, ok_within = _summary(_log_errors(ok, lambda r: r["e_pa"]))
    covered = [
        (r["low_pa"] is None or r["low_pa"] <= r["truth_pa"]) and (r["high_pa"] is None or r["truth_pa"] <= r["high_pa"])
        for r in counted
    ]
    soft_covered = [c for c, r in zip(covered, counted, strict=True) if _soft(r)]
    states = Counter(r["state"] for r in rows)
    return {
        "n": len(counted),
        "log10_error": sum(errors) / len(errors) if errors else None,
        "within_10x": sum(e <= 1.0 for e in errors) / len(errors) if errors else None,
        "point_log10_error": point_error,
        "point_within_10x": point_within,
        "ok_only": {"n": len(ok), "log10_error": ok_error, "within_10x": ok_within},
        **_felt_metrics(counted, display_range_pa),
        "interval_coverage": _mean(covered),
        "soft_n": len(soft_covered),
        "soft_refused": sum(r["state"] == "insufficient_data" and _soft(r) for r in rows),
        "soft_interval_coverage": _mean(soft_covered),
        "states": {s: states.get(s, 0) for s in STATES},
    }


def summarise(rows: Sequence[dict[str, Any]], methods: Sequence[str], *,
              display_range_pa: tuple[float, float] | None = None,
              interval_levels: Mapping[str, float | None] | None = None) -> dict[str, Any]:
    """Per-method metrics, overall and per material and shape (module docstring).

    Parameters
    ----------
    rows : sequence of dict
        Scored rows (:func:`estimator.evaluation.evaluate.result_row`); rows of other methods and
        skipped records are ignored.
    methods : sequence of str
        The methods to summarise, in the order of the result.
    display_range_pa : (float, float), optional
        The softness display's ``(e_soft_pa, e_rigid_pa)``; needed for the felt and width
        figures, which are None without it.
    interval_levels : mapping, optional
        Nominal coverage of each method's intervals (a learned model's); a method not in it
        gets None.

    Returns
    -------
    dict
        Method name to its metrics.
    """
    levels = interval_levels or {}
    out = {}
    for method in methods:
        mine = [r for r in rows if r.get("method") == method]
        groups: dict[str, dict[str, list]] = {"material": defaultdict(list), "shape": defaultdict(list)}
        for r in mine:
            for key, group in groups.items():
                group[r[key]].append(r)
        out[method] = {
            **_metrics(mine, display_range_pa=display_range_pa),
            "interval_level": levels.get(method),
            "per_material": {k: _metrics(v, display_range_pa=display_range_pa)
                             for k, v in sorted(groups["material"].items())},
            "per_shape": {k: _metrics(v, display_range_pa=display_range_pa)
                          for k, v in sorted(groups["shape"].items())},
            "paper": PAPER.get(method),
        }
    return out
