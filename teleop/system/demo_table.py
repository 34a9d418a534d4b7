"""How ``teleop demo`` shows its grasps: the live status lines and the closing table.

The table shows what the softness display rendered for each grasp's final estimate: ``rigid``
(at or beyond the display's stiff end, the sensor's resolution limit unless the settings set
another), ``unknown`` (no usable estimate: the display goes free) or the fraction of the display's
range with the modulus that fraction stands for on the logarithmic scale (``0.62 ~2.1e+05``).
A grasp the robot node cut short (a robot_notice ended it: its watchdog stopped the fingers, or a
gripper command failed) shows ``cut: <event>`` in a last ``note`` column and a line below the table
with the notice's reason, so that its missing or refused estimate is not read as the estimator's
failing. Below the table a line says what the operator felt (:func:`felt_summary`, whose figures
``teleop demo --json`` gives as ``summary``: a cut grasp without a rendering counts as not rendered)
and a line names the learned model(s) whose final estimates it shows (:func:`models_line`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

if TYPE_CHECKING:
    from teleop.system.outcome import GraspOutcome

__all__ = ["LiveView", "closing_table", "cut_cell", "cut_line", "display_cell", "felt_figures",
           "felt_summary", "felt_text", "models_answered", "models_line", "rigid_pa", "signed_decades"]


def _pa(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def _modulus(state: str, e_pa: float | None, unit: str = "") -> str:
    """An estimate's modulus with its state's mark (``>=1e+06``); "none" without one (a refusal)."""
    return "none" if e_pa is None else f"{_STATE_MARK[state]}{_pa(e_pa)}{unit}"


def _number(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def signed_decades(value: float | None) -> str:
    """A felt offset (decades; negative: felt softer than the label) signed, to two places: ``+0.27``,
    ``-0.48``; ``-`` for None. A small negative one reads ``+0.00``, never ``-0.00``."""
    return "-" if value is None else format(round(value, 2) + 0.0, "+.2f")


# The states that carry a modulus (a refusal and a grasp without a final have none: _modulus).
_STATE_MARK = {"ok": "", "lower_bound": ">=", "upper_bound": "<="}


def rigid_pa(display_range: tuple[float, float] | None) -> float | None:
    """The modulus a rigid rendering is shown and felt at: the rigid end of the display's range
    ``display_range`` (e_soft_pa, e_rigid_pa), whatever modulus the estimate carried (a bound, at or
    beyond it) or a rendering still ramping up to it says; None without a range."""
    return None if display_range is None else display_range[1]


def display_cell(outcome: GraspOutcome) -> str:
    """What the display rendered for the final estimate: ``rigid >=E``, ``unknown``, or the fraction of
    the display's range and the modulus it stands for (``0.62 ~2.1e+05``); ``-`` without a final."""
    rendered = outcome.rendered
    if rendered is None:
        return "-"
    if rendered.unknown:
        return "unknown"
    if rendered.rigid:
        rigid_end = rigid_pa(outcome.display_range)
        return "rigid" if rigid_end is None else f"rigid >={_pa(rigid_end)}"
    cell = f"{rendered.stiffness:.2f}"
    return cell if outcome.display_range is None else f"{cell} ~{_pa(outcome.display_e_pa)}"


def cut_cell(outcome: GraspOutcome) -> str:
    """``cut: <event>`` for a grasp a robot_notice ended (:attr:`GraspOutcome.ended_by`), ``-`` otherwise."""
    notice = outcome.ended_by
    return "-" if notice is None else f"cut: {notice.event}"


def cut_line(outcome: GraspOutcome) -> str | None:
    """What cut the grasp short, in one line with the notice's reason; None for a grasp that ran its course."""
    notice = outcome.ended_by
    if notice is None:
        return None
    return f"{outcome.obj.name} ({outcome.grasp_id}) cut by the robot node ({notice.event}): {notice.reason}"


class LiveView:
    """One status line per grasp: updated in place on a terminal, printed once when done otherwise."""

    def __init__(self, out: TextIO, total: int, *, enabled: bool = True):
        self.out = out
        self.total = total
        self.enabled = enabled
        self.tty = enabled and out.isatty()

    def line(self, number: int, outcome: GraspOutcome) -> str:
        head = f"[{number}/{self.total}] {outcome.obj.name:<26}"
        if not outcome.done:
            latest = outcome.latest
            if latest is None:
                return f"{head} {'grasping' if outcome.started else 'simulating'}"
            kind = "provisional" if latest.provisional else "final"
            return (f"{head} {outcome.estimates:3d} estimates, {kind} "
                    f"{_modulus(latest.state, latest.E_pa, ' Pa')} ({latest.state})")
        felt = outcome.felt_log10_offset
        first = outcome.t_first_estimate_s
        # As in the closing table: an operator's final waits for the hand to let go, so its latency
        # says nothing; how soon the display followed the squeeze does.
        settled = outcome.t_felt_within_2x_s
        timing = (f"latency {_number(outcome.latency_ms, '.0f')} ms" if outcome.style == "script" else
                  "never felt within 2x" if settled is None else f"felt within 2x {settled:.2f} s after contact")
        cut = "" if outcome.ended_by is None else f", {cut_cell(outcome)}"
        return (f"{head} E {_pa(outcome.obj.modulus_pa)} Pa -> {_modulus(outcome.state, outcome.e_final_pa, ' Pa')} "
                f"({outcome.state}), display {display_cell(outcome)}, "
                f"felt {signed_decades(felt)} dec, "
                f"first estimate {_number(None if first is None else first * 1e3, '.0f')} ms, {timing}{cut}")

    def update(self, number: int, outcome: GraspOutcome) -> None:
        if self.tty:
            self.out.write("\r\033[K" + self.line(number, outcome))
            self.out.flush()

    def finish(self, number: int, outcome: GraspOutcome) -> None:
        if self.tty:
            self.out.write("\r\033[K")
        if self.enabled:
            print(self.line(number, outcome), file=self.out, flush=True)


def closing_table(outcomes: Sequence[GraspOutcome]) -> str:
    """The closing table: object, grasp style, true E, final estimate and state, what the display
    rendered (:func:`display_cell`), the felt error (decades from the label on the display's range to
    the rendering, negative when felt too soft: a rigid object rendered rigid is exact, whatever the
    bound), first estimate, the time from contact until the display stayed within a factor 2 of the
    label, latency, and when a grasp was cut short a note (:func:`cut_cell`); then a line per cut grasp
    (:func:`cut_line`), the line of :func:`felt_summary` (:func:`felt_text`) and :func:`models_line`.

    The latency runs from the last loading frame to the display report of the final estimate; an
    operator's grasp has its final when the operator lets go, seconds after the peak, so it shows
    none (its provisional estimates follow the squeeze instead: see the felt time), and a table of
    operator grasps alone has no latency column.
    """
    header = ("object", "style", "E true (Pa)", "final (Pa)", "state", "display (~Pa)", "felt (dec)", "first est. (ms)",
              "felt 2x (s)", "latency (ms)")
    rows = [(o.obj.name, o.style, _pa(o.obj.modulus_pa), _modulus(o.state, o.e_final_pa), o.state,
             display_cell(o), signed_decades(o.felt_log10_offset),
             _number(None if o.t_first_estimate_s is None else o.t_first_estimate_s * 1e3, ".0f"),
             _number(o.t_felt_within_2x_s, ".2f"),
             _number(o.latency_ms, ".0f")) for o in outcomes]
    if not any(o.style == "script" for o in outcomes):
        header, rows = header[:-1], [row[:-1] for row in rows]
    if any(o.ended_by is not None for o in outcomes):
        header, rows = (*header, "note"), [(*row, cut_cell(o)) for row, o in zip(rows, outcomes, strict=True)]
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    lines = ["  ".join(str(cell).ljust(w) if i == 0 else str(cell).rjust(w)
                       for i, (cell, w) in enumerate(zip(row, widths, strict=True))) for row in (header, *rows)]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.extend(line for o in outcomes if (line := cut_line(o)) is not None)
    lines.append(felt_text(felt_summary(outcomes)))
    lines.append(models_line(outcomes))
    return "\n".join(lines)


def models_answered(outcomes: Sequence[GraspOutcome]) -> dict[str, int]:
    """How many final estimates each learned model made (by id, in the order they first answered)."""
    counts: dict[str, int] = {}
    for o in outcomes:
        if o.model is not None:
            counts[o.model] = counts.get(o.model, 0) + 1
    return counts


def models_line(outcomes: Sequence[GraspOutcome]) -> str:
    """Which learned models answered, in one line: ``model: default-1a2b3c4d (3 of 3 finals)``, several
    in the order they first answered (the estimator switched models during the run), and the finals
    no model made (analytical)."""
    counts = models_answered(outcomes)
    finals = sum(o.final is not None for o in outcomes)
    analytical = finals - sum(counts.values())
    if not counts:
        return f"model: none (analytical estimates, {finals} of {len(outcomes)} finals)"
    named = ", ".join(f"{model} ({n} of {finals} finals)" for model, n in counts.items())
    return (f"model{'s' if len(counts) > 1 else ''}: {named}"
            + (f"; analytical: {analytical}" if analytical else ""))


def felt_summary(outcomes: Sequence[GraspOutcome]) -> dict[str, Any]:
    """The figures of what the operator felt over ``outcomes`` (:func:`felt_figures`): the closing
    table's line (:func:`felt_text`) and ``teleop demo --json``'s ``summary``."""
    felt = [o for o in outcomes if o.felt_log10_error is not None]
    display_range = felt[0].display_range if felt else (0.0, 0.0)
    return felt_figures([(o.obj.modulus_pa, o.display_e_pa) for o in felt], display_range, grasps=len(outcomes))


def felt_figures(felt: Sequence[tuple[float, float]], display_range: tuple[float, float], *,
                 grasps: int) -> dict[str, Any]:
    """What the operator felt, from the (label, rendered modulus) pairs (Pa) of the ``grasps`` the
    display rendered a modulus for: each rendering against the label clipped to the display's range
    ``display_range`` (e_soft_pa, e_rigid_pa; an object stiffer than its rigid end is right when
    rendered rigid).

    Returns
    -------
    dict
        ``grasps``; ``rendered``, those the display rendered a modulus for, and ``not_rendered``
        (no estimate, or shown unknown); ``mean_error_decades``, the mean felt error; ``within_2x``,
        the renderings within a factor 2; ``dangerous_misses``
        (:func:`estimator.evaluation.metrics.dangerous_miss`). The last three are None when the
        display rendered none.
    """
    from estimator.evaluation.metrics import dangerous_miss, felt_log10_error, felt_within

    figures: dict[str, Any] = {"grasps": grasps, "rendered": len(felt), "not_rendered": grasps - len(felt),
                               "mean_error_decades": None, "within_2x": None, "dangerous_misses": None}
    if felt:
        errors = [felt_log10_error(e_pa, label, display_range_pa=display_range) for label, e_pa in felt]
        # Plain int and float: a rendering read through numpy makes numpy scalars, which json refuses.
        figures.update(mean_error_decades=float(np.mean(errors)), within_2x=int(sum(map(felt_within, errors))),
                       dangerous_misses=int(sum(dangerous_miss(label, e_pa, e_rigid_pa=display_range[1])
                                                for label, e_pa in felt)))
    return figures


def felt_text(figures: dict[str, Any]) -> str:
    """The figures of :func:`felt_figures` in one line, the mean error to two places."""
    if not figures["rendered"]:
        return f"the display rendered none of {figures['grasps']} grasps"
    unrendered = figures["not_rendered"]
    return (f"felt (display against the label on its range): mean error {figures['mean_error_decades']:.2f} "
            f"decades, {figures['within_2x']} of {figures['grasps']} within a factor 2, "
            f"{figures['dangerous_misses']} dangerous misses"
            + (f", {unrendered} not rendered" if unrendered else ""))
