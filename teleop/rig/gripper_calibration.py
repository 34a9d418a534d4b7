"""``teleop calibrate gripper``: the fingers' stiffness, from squeezing a rigid reference object.

The estimator corrects every width the gripper reports for the fingers bending open under
the grip force: the fingertips are ``width + F / k`` apart (``gripper.finger_stiffness_n_per_m``,
read by the no-tactile and elastic fits; the simulator bends its fingers the same way). On a
rigid object of width W the tips cannot close further than W, so the reported width is

    width = W - F / k

and a line of the width against the force measured by the load cell has slope -1/k.

The command tares the load cell with the fingers open, then, ``--repeats`` times, squeezes the
reference at ``--levels`` forces from a quarter of ``--max-force-n`` up to it: open to W + 10 mm,
grasp (commanded to ``W - F / k_configured``, where the configured stiffness puts the fingers at
that force, so a position-controlled hand squeezes as far as a force-controlled one), wait
``--settle-s``, then average the load cell and the width readings over ``--average-s``. The
fit (:func:`fit_finger_stiffness`) is least squares over all squeezes; its uncertainty is the
slope's standard error, and each repeat's own stiffness is reported too; a repeat whose
width does not fall as the force rises (the hand stalled, the reference slipped) refuses the fit.

Use a reference that is rigid where the fingers touch it (a steel gauge block), held so that the
load-cell finger presses on it. Everything between the motor and the block yields with the force
(fingers, mounts, and the gels if the block presses on them): the fitted k is all of it together.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from teleop.clikit import non_negative_number, positive_number
from teleop.devices.gripper import Gripper, make_gripper
from teleop.devices.loadcell import LoadCell, make_load_cell
from teleop.devices.simulated import is_simulated
from teleop.errors import DeviceError, InvalidCommandError, SettingsError
from teleop.rig.conclude import conclude
from teleop.rig.load_cell_calibration import load_cell_source
from teleop.settings import MIN_FINGER_STIFFNESS_N_PER_M, GripperSettings, Settings, load_settings
from teleop.settings_edit import check_writable

__all__ = ["Squeeze", "StiffnessFit", "fit_finger_stiffness", "squeeze_reference"]

CLEARANCE_M = 0.01  # the fingers open this far beyond the object between squeezes
MAX_CONTACT_MISMATCH_M = 0.005  # the fitted contact width may differ this much from the stated object width


@dataclass(frozen=True)
class Squeeze:
    """One squeeze at rest: ``repeat`` number, commanded force, measured force (mean, std) and width."""

    repeat: int
    commanded_force_n: float
    force_n: float
    force_std_n: float
    width_m: float


@dataclass(frozen=True)
class StiffnessFit:
    """The result of :func:`fit_finger_stiffness`; falsy, with ``reason``, when refused.

    ``stiffness_n_per_m`` with its standard error ``stiffness_se_n_per_m``; ``contact_width_m``
    the width at zero force (the line's intercept); ``per_repeat_n_per_m`` each repeat's own fit;
    ``residual_m`` the rms miss of the line.
    """

    stiffness_n_per_m: float
    stiffness_se_n_per_m: float
    contact_width_m: float
    residual_m: float
    per_repeat_n_per_m: tuple[float, ...]
    n: int
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason

    def as_dict(self) -> dict:
        return {**dataclasses.asdict(self), "ok": bool(self)}


def _line(force: np.ndarray, width: np.ndarray) -> tuple[float, float, float, float]:
    """Least squares ``width = intercept + slope * force``: (slope, its standard error, intercept, rms residual)."""
    f_c = force - force.mean()
    sxx = float(f_c @ f_c)
    slope = float(f_c @ (width - width.mean())) / sxx
    intercept = float(width.mean() - slope * force.mean())
    residual = width - (intercept + slope * force)
    dof = force.size - 2
    se = math.sqrt(float(residual @ residual) / dof / sxx) if dof > 0 else math.inf
    return slope, se, intercept, math.sqrt(float(residual @ residual) / force.size)


def fit_finger_stiffness(
    squeezes: Sequence[Squeeze],
    *,
    object_width_m: float | None = None,
    max_relative_se: float = 0.05,
    min_force_span_n: float = 2.0,
    min_contact_force_n: float = 0.5,
) -> StiffnessFit:
    """The fingers' stiffness k from squeezes of a rigid object: ``width = W - F / k``.

    Parameters
    ----------
    squeezes : sequence of Squeeze
        At least three, at different forces.
    object_width_m : float, optional
        The reference's width: refuse a fit whose contact width (intercept) is more than 5 mm
        from it (the fingers closed on something else, or on nothing).
    max_relative_se : float
        Refuse a stiffness whose standard error is a larger fraction of it.
    min_force_span_n : float
        Refuse squeezes whose forces span less than this (N).
    min_contact_force_n : float
        Squeezes that read less force (N) did not reach the object and are left out.

    Returns
    -------
    StiffnessFit
        Falsy with the reason when refused.
    """
    squeezes = [s for s in squeezes if s.force_n >= min_contact_force_n]
    force = np.array([s.force_n for s in squeezes], dtype=np.float64)
    width = np.array([s.width_m for s in squeezes], dtype=np.float64)
    nan = math.nan
    if force.size < 3 or np.ptp(force) < min_force_span_n:
        span = float(np.ptp(force)) if force.size else 0.0
        return StiffnessFit(nan, nan, nan, nan, (), force.size, reason=(
            f"{force.size} squeezes reached the object (>= {min_contact_force_n:g} N), spanning {span:.3g} N: need at "
            f"least 3 spanning {min_force_span_n:g} N; does the load cell read the grip (is it in the finger that "
            "presses on the object)?"))
    slope, se, intercept, rms = _line(force, width)
    repeat_slopes = {}
    for repeat in sorted({s.repeat for s in squeezes}):
        mine = [i for i, s in enumerate(squeezes) if s.repeat == repeat]
        if len(mine) >= 2 and np.ptp(force[mine]) > 0:
            repeat_slopes[repeat] = _line(force[mine], width[mine])[0]
    per_repeat = tuple(-1.0 / s if s else math.inf for s in repeat_slopes.values())
    stiffness = -1.0 / slope if slope else math.inf
    result = StiffnessFit(stiffness, se / slope**2 if slope else math.inf, intercept, rms, per_repeat, force.size)
    if not slope < 0:
        return dataclasses.replace(result, reason=(
            f"the width does not fall as the force rises (slope {slope * 1e6:+.3g} um/N): is the reference between "
            "the fingers, and rigid?"))
    # A repeat whose widths stay put (the hand stalled) or rise cannot be the same fingers
    # squeezing the same reference: pooled with the others it would only bias k.
    not_falling = {repeat + 1: s for repeat, s in repeat_slopes.items() if not s < 0}
    if not_falling:
        slopes = ", ".join(f"{s * 1e6:+.3g} um/N in repeat {r}" for r, s in not_falling.items())
        return dataclasses.replace(result, reason=(
            f"the width does not fall as the force rises ({slopes}): did the fingers stall or the reference "
            "slip in that repeat?"))
    if object_width_m is not None and abs(intercept - object_width_m) > MAX_CONTACT_MISMATCH_M:
        return dataclasses.replace(result, reason=(
            f"the fingers touch at {intercept * 1e3:.1f} mm, not near the {object_width_m * 1e3:.1f} mm reference: "
            "is it between the fingers, and --object-width-mm right?"))
    most = next(f for f in dataclasses.fields(GripperSettings) if f.name == "finger_stiffness_n_per_m").metadata["hi"]
    if not MIN_FINGER_STIFFNESS_N_PER_M <= stiffness <= most:
        return dataclasses.replace(result, reason=(
            f"k = {stiffness:.4g} N/m is outside what the settings take ({MIN_FINGER_STIFFNESS_N_PER_M:g} to "
            f"{most:g} N/m; fingers with a gel pad are 2e4-5e5 N/m): is the reference rigid, and the load cell "
            "calibrated?"))
    if result.stiffness_se_n_per_m > max_relative_se * stiffness:
        return dataclasses.replace(result, reason=(
            f"too uncertain: k = {stiffness:.4g} +- {result.stiffness_se_n_per_m:.2g} N/m (standard error above "
            f"{100 * max_relative_se:g} %): the widths scatter by {rms * 1e6:.3g} um rms; use a rigid reference "
            "held still, more --repeats or a higher --max-force-n"))
    return result


# --------------------------------------------------------------------------- squeezing


def _mean_force(cell: LoadCell, duration_s: float) -> tuple[float, float]:
    cell.read()  # forces from before the hold
    chunks, end = [], time.monotonic() + duration_s
    while time.monotonic() < end or not chunks:
        chunks.append(cell.read().value)
    forces = np.concatenate(chunks)
    return float(forces.mean()), float(forces.std())


def squeeze_reference(
    gripper: Gripper,
    cell: LoadCell,
    *,
    object_width_m: float,
    forces_n: Sequence[float],
    repeats: int,
    configured_stiffness_n_per_m: float,
    speed_m_s: float,
    settle_s: float,
    average_s: float,
) -> list[Squeeze]:
    """Squeeze the reference at each force, ``repeats`` times (see the module notes); connected devices."""
    open_m = min(object_width_m + CLEARANCE_M, gripper.max_width_m)
    squeezes = []
    for repeat in range(repeats):
        for force in forces_n:
            if not gripper.move(open_m, speed_m_s=speed_m_s):
                raise DeviceError(f"{gripper!r}: could not open to {open_m * 1e3:.1f} mm before a squeeze")
            target = max(0.0, object_width_m - force / configured_stiffness_n_per_m)
            gripper.grasp(target, speed_m_s=speed_m_s, force_n=force, epsilon_inner_m=object_width_m,
                          epsilon_outer_m=CLEARANCE_M)
            time.sleep(settle_s)
            gripper.widths()  # widths from before the hold
            mean_n, std_n = _mean_force(cell, average_s)
            widths = gripper.widths(timeout_s=1.0)
            width = float(widths.value.mean()) if len(widths) else gripper.read_width()[1]
            squeezes.append(Squeeze(repeat, force, mean_n, std_n, width))
            print(f"repeat {repeat + 1}/{repeats}, {force:.3g} N commanded: {mean_n:.3g} N measured, "
                  f"width {width * 1e3:.3f} mm", file=sys.stderr, flush=True)
    gripper.move(open_m, speed_m_s=speed_m_s)
    return squeezes


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n", 1)[1].replace(":func:", "").replace("``", "")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--settings", required=True, metavar="FILE",
                        help="settings TOML of the rig: [gripper] and [load_cell] are used, and "
                             "gripper.finger_stiffness_n_per_m is written back into it")
    parser.add_argument("--object-width-mm", type=float, required=True, metavar="W",
                        help="width of the rigid reference between the fingers, in mm (calipers)")
    parser.add_argument("--repeats", type=int, default=3, metavar="N", help="squeeze sweeps (default: 3)")
    parser.add_argument("--levels", type=int, default=4, metavar="N", help="forces per sweep (default: 4)")
    parser.add_argument("--max-force-n", type=float, default=None, metavar="F",
                        help="largest squeeze force in N (default: gripper.target_force_n)")
    parser.add_argument("--settle-s", type=non_negative_number, default=0.3, metavar="S",
                        help="wait after each grasp stops before reading (default: 0.3)")
    parser.add_argument("--average-s", type=positive_number, default=0.5, metavar="S",
                        help="seconds of force and width readings averaged per squeeze (default: 0.5)")
    parser.add_argument("--max-se-percent", type=positive_number, default=5.0, metavar="P",
                        help="refuse a stiffness whose standard error is above P %% of it (default: 5.0)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object (fit, squeezes, changes) on stdout")


def _check(args: argparse.Namespace, settings: Settings) -> tuple[float, list[float]]:
    if is_simulated("load cell", settings.load_cell.backend):
        raise SettingsError(f"load_cell.backend = {settings.load_cell.backend!r} is simulated: it only replays "
                            "simulated grasps and cannot feel this squeeze: calibrate with the rig's cell ('serial' or 'tcp')")
    width_m = args.object_width_mm * 1e-3
    if not 0 < width_m < settings.gripper.max_width_m:
        raise InvalidCommandError(f"--object-width-mm {args.object_width_mm:g}: expected a width between 0 and the "
                                  f"gripper's {settings.gripper.max_width_m * 1e3:g} mm")
    if args.repeats < 1 or args.levels < 2:
        raise InvalidCommandError(f"--repeats {args.repeats} --levels {args.levels}: expected >= 1 and >= 2")
    top = settings.gripper.target_force_n if args.max_force_n is None else args.max_force_n
    if not 0 < top <= 140.0:
        raise InvalidCommandError(f"--max-force-n {top:g}: expected a force in (0, 140] N")
    return width_m, np.linspace(top / 4, top, args.levels).tolist()


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    width_m, forces = _check(args, settings)
    check_writable(args.settings)
    gripper, cell = make_gripper(settings.gripper), make_load_cell(settings.load_cell)
    try:
        gripper.connect()
        gripper.move(min(width_m + CLEARANCE_M, gripper.max_width_m))
        try:
            cell.connect()
            cell.tare()  # fingers open: nothing presses on the cell
        except DeviceError as exc:
            raise DeviceError(f"{exc}: check {load_cell_source(settings.load_cell)}") from exc
        squeezes = squeeze_reference(
            gripper, cell, object_width_m=width_m, forces_n=forces, repeats=args.repeats,
            configured_stiffness_n_per_m=settings.gripper.finger_stiffness_n_per_m,
            speed_m_s=settings.gripper.closing_speed_m_s, settle_s=args.settle_s, average_s=args.average_s)
    finally:
        cell.close()
        gripper.close()
    fit = fit_finger_stiffness(squeezes, object_width_m=width_m, max_relative_se=args.max_se_percent / 100)
    spread = ", ".join(f"{k:.4g}" for k in fit.per_repeat_n_per_m)
    return conclude(
        "gripper", args.settings, as_json=args.json, refused=fit.reason,
        report={**fit.as_dict(), "squeezes": [dataclasses.asdict(s) for s in squeezes]},
        changes={"gripper.finger_stiffness_n_per_m": float(f"{fit.stiffness_n_per_m:.4g}")} if fit else {},
        summary=f"finger stiffness {fit.stiffness_n_per_m:.4g} +- {fit.stiffness_se_n_per_m:.2g} N/m (standard error; "
                f"per repeat: {spread}); contact at {fit.contact_width_m * 1e3:.2f} mm, rms miss "
                f"{fit.residual_m * 1e6:.3g} um")
