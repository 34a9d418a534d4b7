"""What the scripts here share with the ``teleop``, ``estimator`` and ``haptics`` commands: bad options
refused by argparse with what was expected; the project's own errors (every one a
:class:`~teleop.errors.ComplianceTeleopError`) printed as one line with exit status 2, never a
traceback or figures of nothing; Ctrl-C, SIGTERM and SIGHUP stopping a script as they stop a command
(its child processes stopped, its temporary files removed, one line, status 130, 143 or 129).

And the yardstick every speed figure is also given in (:class:`Baseline`): the project rule wants
ratios against a baseline run in the same process, so that runs on a busy or a slow machine compare.

A script imports it by name (``python benchmarks/NAME.py`` puts this folder first on ``sys.path``)."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from teleop.clikit import say_stopped, sigterm_as_ctrl_c
from teleop.errors import ComplianceTeleopError

CHILD_STOP_S = 30.0  # a child stopped by SIGTERM gets this long to stop its own children before it is killed


class BenchmarkError(ComplianceTeleopError):
    """A benchmark that could not measure what it times (nothing matched, every grasp refused)."""


def run_script(parser: argparse.ArgumentParser, work: Callable[[argparse.Namespace], int | None]) -> int:
    """Parse the command line and run ``work`` on it, SIGTERM and SIGHUP raising as Ctrl-C does; its exit status.

    Parameters
    ----------
    parser
        The script's options; its ``prog`` starts every line said on stderr.
    work
        The script's body; its return value (None: 0) is the exit status.

    Returns
    -------
    int
        ``work``'s status; 2 after a :class:`~teleop.errors.ComplianceTeleopError`; 128 plus the signal's
        number after Ctrl-C (130), SIGTERM (143) or SIGHUP (129), said as ``PROG: interrupted`` (or
        ``terminated``, ``hung up``) once ``work``'s clean-up ran.
    """
    args = parser.parse_args()
    try:
        with sigterm_as_ctrl_c():
            return int(work(args) or 0)
    except ComplianceTeleopError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (sigterm_as_ctrl_c)
        return say_stopped(parser.prog, exc)


def run_child(line: Sequence[str]) -> subprocess.CompletedProcess:
    """Run ``line`` to its end, its output captured as text; stopped with this script.

    The child runs in a session of its own, so a Ctrl-C at the terminal reaches this process alone;
    an interrupt here (Ctrl-C, SIGTERM under :func:`run_script`) sends the child one SIGTERM (the
    project's commands then stop as on Ctrl-C, children and all), waits :data:`CHILD_STOP_S` for it,
    kills it past that (or on a second interrupt meanwhile), and raises on.
    """
    with subprocess.Popen(line, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          start_new_session=True) as child:
        try:
            out, err = child.communicate()
        except KeyboardInterrupt:
            child.send_signal(signal.SIGTERM)
            try:
                child.communicate(timeout=CHILD_STOP_S)
            except subprocess.TimeoutExpired:
                pass
            finally:  # past the wait, or a second interrupt cut it short: its own session hears no Ctrl-C
                if child.poll() is None:
                    child.kill()
            raise
    return subprocess.CompletedProcess(line, child.returncode, out, err)


class Baseline:
    """One tactile frame's perception timed in this process: the machine's speed at the time.

    The same workload as ``teleop bench-latency``'s frame baseline
    (:func:`~teleop.system.latency.frame_baseline_ms`: decode, warp, depth and contact features of a
    simulated ball press on the estimator's finger, with the shipped settings and calibration). A
    script times it :meth:`before <time>` and after its own timing, under the same thread settings,
    and gives each speed figure also in its units (:meth:`ratio`): on a busy or slower machine both
    move together, the ratio much less.
    """

    def __init__(self) -> None:
        from estimator.perception.calibration import load_calibration
        from teleop.settings import load_settings
        from teleop.system.live_system import configured_calibration, simulated_calibration

        self.settings = load_settings()
        path = configured_calibration(self.settings)
        if path is None:  # settings without a calibration file: fitted as the demo fits one
            with tempfile.TemporaryDirectory() as folder:
                self.calibration = load_calibration(simulated_calibration(self.settings, Path(folder)))
        else:
            self.calibration = load_calibration(path)
        self.runs: list[list[float]] = []

    def time(self) -> None:
        """Time the workload (:data:`~teleop.system.latency.BASELINE_REPEATS` frames): before the
        script's own timing, and again after it."""
        from teleop.system.latency import frame_baseline_ms

        self.runs.append(frame_baseline_ms(self.settings, self.calibration))

    def figures(self) -> dict[str, float]:
        """``frame_baseline_ms`` (the median over both runs), ``frame_baseline_before_ms`` and
        ``frame_baseline_after_ms``, as ``teleop bench-latency`` names them."""
        from teleop.system.latency import baseline_figures

        if not self.runs:
            raise BenchmarkError("the frame baseline was not timed: call Baseline.time() first")
        return baseline_figures(self.runs[0], self.runs[-1])

    def ratio(self, ms: float | None) -> float | None:
        """``ms`` in frame baselines (None stays None)."""
        return None if ms is None else ms / self.figures()["frame_baseline_ms"]

    def line(self) -> str:
        """The baseline in one line: its median, before and after the script's timing."""
        f = self.figures()
        return (f"frame baseline (one tactile frame's perception in this process, as teleop bench-latency): "
                f"{f['frame_baseline_ms']:.3f} ms (before {f['frame_baseline_before_ms']:.3f}, after "
                f"{f['frame_baseline_after_ms']:.3f}); 'bl': in its units")
