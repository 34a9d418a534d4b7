"""``teleop calibrate load-cell``: the HX711 cell's tare and counts per newton from known masses.

The cell is read in raw counts through its configured backend (``serial`` or ``tcp``; the
``sim`` cell delivers newtons and has nothing to calibrate). First the tare: the mean of the
unloaded cell. Then, for each known mass m, the mean counts with it on the cell; the load is
``F = m g`` (g = 9.80665 m/s^2). The fit (:func:`fit_load_cell`) is counts per newton by
least squares through the tare, ``counts - tare = c F``; it refuses the cell, saying why, when

* a mass reads no change from the tare (not on the cell, or the cell not wired);
* the counts fall under load (the signal wires swapped);
* the readings scatter (std of single readings, pooled over all levels) by more than
  ``max_noise_fraction`` of full scale (the largest load): a noisy cell or a reading that
  never settled;
* the fit misses a mass by more than ``max_residual_fraction`` of full scale: a non-linear
  (overloaded, side-loaded or damaged) cell. With one mass the line passes exactly through
  it: use two or more, the largest near the loads of a grasp, to check linearity.

How a mass counts as placed
---------------------------
Interactively each mass is confirmed with Enter. With ``--mass-g`` nobody presses a key:
for each mass in turn the command waits (up to ``--place-timeout-s``) until the median of
the last three readings departs from the previous level (the tare, then the mass before)
by more than ``max(10 x the tare's noise std, 20 counts)``, waits ``--settle-s`` for the
swing to die down, then averages ``--average-s`` of readings. So add or swap the masses in
the order given, one at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from teleop.clikit import non_negative_number, positive_number
from teleop.devices.loadcell import LoadCell, make_load_cell
from teleop.devices.simulated import is_simulated
from teleop.errors import (
    DeviceError,
    DeviceStalledError,
    DeviceTimeoutError,
    SettingsError,
    TeleopError,
)
from teleop.redact import redact_url
from teleop.rig.conclude import conclude, say
from teleop.settings import LoadCellSettings, load_settings
from teleop.settings_edit import check_writable

__all__ = ["G_M_S2", "Level", "LoadCellFit", "fit_load_cell", "load_cell_source", "read_level", "wait_for_level"]

G_M_S2 = 9.80665  # standard gravity: the load of a mass
DEPART_SIGMA = 10.0  # a placed mass moves the reading by more than this many noise std...
DEPART_MIN_COUNTS = 20.0  # ...and at least this many counts (a noiseless cell still needs a step)
NO_CHANGE_SIGMA = 5.0  # a mass whose mean moved less than this many noise std...
NO_CHANGE_MIN_COUNTS = 2.0  # ...or this many counts "reads no change"


@dataclass(frozen=True)
class Level:
    """The cell at rest under one load: ``mass_g`` (0 for the tare) and its raw counts' statistics."""

    mass_g: float
    mean_counts: float
    std_counts: float
    n: int

    @property
    def force_n(self) -> float:
        return self.mass_g * 1e-3 * G_M_S2


@dataclass(frozen=True)
class LoadCellFit:
    """The result of :func:`fit_load_cell`; falsy, with ``reason``, when the cell is refused.

    ``residual_n`` is the largest miss of the fit at any mass (N), ``residual_fraction`` that
    over full scale (the largest load, ``full_scale_n``); ``noise_n`` the pooled std of single
    readings in N.
    """

    tare_counts: float
    counts_per_n: float
    residual_n: float
    residual_fraction: float
    noise_n: float
    full_scale_n: float
    levels: tuple[Level, ...]
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason

    def as_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["ok"] = bool(self)
        return out


def fit_load_cell(
    tare: Level,
    loaded: Sequence[Level],
    *,
    max_residual_fraction: float = 0.01,
    max_noise_fraction: float = 0.005,
) -> LoadCellFit:
    """Counts per newton through the tare from the cell's readings under known masses.

    Parameters
    ----------
    tare : Level
        The unloaded cell.
    loaded : sequence of Level
        One per known mass (``mass_g`` > 0).
    max_residual_fraction : float
        Largest miss of the line at any mass, as a fraction of full scale, before the cell
        counts as non-linear.
    max_noise_fraction : float
        Largest std of single readings, as a fraction of full scale, before the cell counts
        as noisy.

    Returns
    -------
    LoadCellFit
        Falsy with the reason when the cell is refused (module notes).
    """
    if not loaded or any(not (lv.mass_g > 0) for lv in loaded):
        raise TeleopError(f"fit_load_cell: masses {[lv.mass_g for lv in loaded]} g: expected at least one, each > 0 g")
    levels = (tare, *loaded)
    force = np.array([lv.force_n for lv in loaded])
    change = np.array([lv.mean_counts for lv in loaded]) - tare.mean_counts
    variances = [lv.std_counts**2 for lv in levels]
    noise_counts = math.sqrt(np.average(variances, weights=[max(lv.n - 1, 1) for lv in levels]))
    full_scale = float(force.max())
    slope = float(force @ change / (force @ force))
    residual_n = float(np.max(np.abs(change / slope - force))) if slope else math.inf
    noise_n = noise_counts / abs(slope) if slope else math.inf

    def result(reason: str = "") -> LoadCellFit:
        return LoadCellFit(tare.mean_counts, slope, residual_n, residual_n / full_scale, noise_n, full_scale,
                           levels, reason)

    for level, moved in zip(loaded, change, strict=True):
        if abs(moved) <= max(NO_CHANGE_SIGMA * noise_counts, NO_CHANGE_MIN_COUNTS):
            return result(f"the {level.mass_g:g} g mass reads no change from the tare ({moved:+.0f} counts, noise "
                          f"{noise_counts:.1f} counts): is it on the cell, and the cell wired to the HX711?")
    if slope <= 0:
        return result(f"the counts fall under load ({slope:.4g} counts per N): swap the cell's signal wires "
                      "(A+ and A-) or mount it the other way up")
    if noise_n > max_noise_fraction * full_scale:
        return result(f"noisy: single readings scatter by {noise_n:.3g} N (std, {100 * noise_n / full_scale:.2g} % "
                      f"of the {full_scale:.3g} N full scale, limit {100 * max_noise_fraction:g} %): keep the cell "
                      "still, shield and shorten the cable, ground the HX711")
    if residual_n > max_residual_fraction * full_scale:
        return result(f"non-linear: the line through the tare misses a mass by {residual_n:.3g} N "
                      f"({100 * residual_n / full_scale:.2g} % of full scale, limit {100 * max_residual_fraction:g} %):"
                      " check the cell for side loads, overload or a loose mount")
    return result()


# --------------------------------------------------------------------------- reading the cell


def load_cell_source(settings: LoadCellSettings) -> str:
    """Where the configured cell is read, and the settings key that says so."""
    if settings.backend == "serial":
        return f"{settings.port or '(no port)'} (`load_cell.port`)"
    if settings.backend == "tcp":
        return f"{redact_url(settings.address)} (`load_cell.address`)"
    return "the simulated cell"


def connect_counts_cell(settings: LoadCellSettings) -> LoadCell:
    """The configured cell, connected, reading raw counts (no calibration applied)."""
    if is_simulated("load cell", settings.backend):
        raise SettingsError(f"load_cell.backend = {settings.backend!r} is simulated and delivers newtons, not counts: "
                            "nothing to calibrate; set the backend to 'serial' or 'tcp'")
    cell = make_load_cell(dataclasses.replace(settings, counts_per_n=1.0, tare_counts=0))
    try:
        return cell.connect()
    except DeviceError as exc:
        raise DeviceError(f"{exc}: check {load_cell_source(settings)}") from exc


def _read(cell: LoadCell) -> np.ndarray:
    try:
        return cell.read().value
    except DeviceTimeoutError as exc:
        raise DeviceTimeoutError(f"load cell: no reading from {load_cell_source(cell.settings)} within "
                                 f"{cell.settings.timeout_s} s: check the cable, the bridge and the setting") from exc
    except DeviceStalledError as exc:
        raise DeviceStalledError(f"load cell: {exc}: check the cable, the bridge and the setting") from exc


def read_level(cell: LoadCell, mass_g: float, *, duration_s: float) -> Level:
    """Mean and std of the raw counts read for ``duration_s`` (what came before is dropped)."""
    _read(cell)  # readings from before this level
    chunks, end = [], time.monotonic() + duration_s
    while time.monotonic() < end or not chunks:
        chunks.append(_read(cell))
    counts = np.concatenate(chunks)
    return Level(mass_g, float(counts.mean()), float(counts.std(ddof=1)) if counts.size > 1 else 0.0, counts.size)


def wait_for_level(cell: LoadCell, previous: Level, threshold_counts: float, *, timeout_s: float) -> None:
    """Block until the median of the last three readings departs from ``previous`` by more than
    ``threshold_counts``; DeviceTimeoutError after ``timeout_s``."""
    recent = np.zeros(0)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        recent = np.concatenate([recent, _read(cell)])[-3:]
        if abs(np.median(recent) - previous.mean_counts) > threshold_counts:
            return
    raise DeviceTimeoutError(f"load cell: no new load within {timeout_s:g} s (the reading stayed within "
                             f"{threshold_counts:.0f} counts of the {previous.mass_g:g} g level): place the next mass")


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n", 1)[1].replace(":func:", "").replace("``", "")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--settings", required=True, metavar="FILE",
                        help="settings TOML of the rig: the cell is read through its [load_cell] backend, and "
                             "load_cell.tare_counts and load_cell.counts_per_n are written back into it")
    parser.add_argument("--mass-g", type=positive_number, action="append", metavar="G",
                        help="a known mass in grams, repeatable, in the order you will place them; runs without "
                             "prompts (see 'How a mass counts as placed'). Default: ask for each mass")
    parser.add_argument("--average-s", type=positive_number, default=2.0, metavar="S",
                        help="seconds of readings averaged per level (default: 2.0)")
    parser.add_argument("--settle-s", type=non_negative_number, default=1.0, metavar="S",
                        help="with --mass-g: seconds waited after a mass is seen placed (default: 1.0)")
    parser.add_argument("--place-timeout-s", type=positive_number, default=60.0, metavar="S",
                        help="with --mass-g: longest wait for each mass to be placed (default: 60.0)")
    parser.add_argument("--max-residual-percent", type=positive_number, default=1.0, metavar="P",
                        help="refuse a cell whose fit misses a mass by more than P %% of full scale (default: 1.0)")
    parser.add_argument("--max-noise-percent", type=positive_number, default=0.5, metavar="P",
                        help="refuse a cell whose readings scatter (std) by more than P %% of full scale "
                             "(default: 0.5)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object (fit, levels, changes) on stdout")


def _interactive_levels(cell: LoadCell, args: argparse.Namespace, ask: Callable[[str], str]) -> list[Level]:
    levels = []
    while True:
        answer = ask("Place a known mass on the cell, type its mass in g and press Enter (empty: done): ").strip()
        if not answer:
            return levels
        try:
            mass_g = float(answer)
        except ValueError:
            say(f"not a mass in grams: {answer!r}")
            continue
        if not (math.isfinite(mass_g) and mass_g > 0):  # an infinite mass fitted NaN
            say(f"not a finite mass > 0 g: {answer!r}")
            continue
        levels.append(read_level(cell, mass_g, duration_s=args.average_s))
        say(f"{mass_g:g} g: {levels[-1].mean_counts:.1f} counts")


def _measure(cell: LoadCell, args: argparse.Namespace, ask: Callable[[str], str]) -> tuple[Level, list[Level]]:
    if args.mass_g is None:
        ask("Remove everything from the cell and press Enter: ")
    tare = read_level(cell, 0.0, duration_s=args.average_s)
    say(f"tare: {tare.mean_counts:.1f} counts (std {tare.std_counts:.1f}, {tare.n} readings)")
    if args.mass_g is None:
        return tare, _interactive_levels(cell, args, ask)
    threshold = max(DEPART_SIGMA * tare.std_counts, DEPART_MIN_COUNTS)
    levels, previous = [], tare
    for mass_g in args.mass_g:
        say(f"place {mass_g:g} g on the cell")
        wait_for_level(cell, previous, threshold, timeout_s=args.place_timeout_s)
        time.sleep(args.settle_s)
        previous = read_level(cell, mass_g, duration_s=args.average_s)
        levels.append(previous)
        say(f"{mass_g:g} g: {previous.mean_counts:.1f} counts (std {previous.std_counts:.1f})")
    return tare, levels


def run(args: argparse.Namespace, *, ask: Callable[[str], str] = input) -> int:
    settings = load_settings(args.settings)
    if args.mass_g is None and not sys.stdin.isatty():
        raise SettingsError("no --mass-g given and no terminal to ask in: give the masses with --mass-g")
    check_writable(args.settings)
    cell = connect_counts_cell(settings.load_cell)
    try:
        tare, levels = _measure(cell, args, ask)
    except EOFError as exc:  # Ctrl-D at a prompt
        raise SettingsError("the input ended at a prompt (Ctrl-D): nothing was written; press Enter to go on, "
                            "or Enter alone after the last mass") from exc
    finally:
        cell.close()
    if not levels:
        raise SettingsError("no mass was measured: at least one known mass is needed")
    fit = fit_load_cell(tare, levels, max_residual_fraction=args.max_residual_percent / 100,
                        max_noise_fraction=args.max_noise_percent / 100)
    note = " (one mass: linearity not checked)" if len(levels) == 1 else ""
    return conclude("load cell", args.settings, report=fit.as_dict(), as_json=args.json, refused=fit.reason,
                    changes={"load_cell.tare_counts": round(fit.tare_counts),
                             "load_cell.counts_per_n": float(f"{fit.counts_per_n:.6g}")} if fit else {},
                    summary=f"counts per N {fit.counts_per_n:.6g}, tare {fit.tare_counts:.1f} counts; residual "
                            f"{fit.residual_n:.3g} N ({100 * fit.residual_fraction:.2g} % of {fit.full_scale_n:.3g} "
                            f"N){note}; noise {fit.noise_n:.2g} N")
