"""``haptics operate``: the operator console (:mod:`haptics.console`) on the live system's bus.

It binds the command endpoint (the operator's), subscribes to the robot node's, the
estimator's and the display's endpoints, and drives the gripper from an operator input device
(:mod:`haptics.inputs`) through :class:`~haptics.operator_loop.OperatorLoop`. ``--headless``
runs the same loop without the screen (for the simulated operator, scripts and logs), printing
one line per action.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import json
import logging
import sys
import textwrap
from collections.abc import Iterator
from typing import Any

from haptics.inputs import BACKENDS as INPUT_BACKENDS
from haptics.inputs import input_class, make_input
from haptics.operator_link import OperatorLink
from haptics.operator_loop import LoopStatus, OperatorLoop
from haptics.settings import operator_settings
from teleop.catalogue import default_catalogue_path, load_catalogue
from teleop.clikit import Terminated, on_stop_signals, positive_number
from teleop.errors import SettingsError
from teleop.live import StopSignals, add_endpoint_arguments, bus_from_args
from teleop.settings import default_settings_path, load_settings

HELD_LOG_RECORDS = 200

HELP = """\
Two ways to drive the gripper:

  discrete grasp   g closes the fingers on the object until the grasp force (--force, changed
                   live with + and -, never above the settings' gripper.target_force_n), holds
                   and opens again; r releases, s stops the fingers where they are. On the
                   simulated gripper a discrete grasp replays a grasp simulated whole: it holds
                   and opens by itself, and the robot node refuses r and s until it has ended.
  leader-follower  while the dead-man enable is held, the fingers' target width follows the
                   grip (grip 0 = fully open, 1 = closed), 50 commands a second; the fingers stop
                   closing at the settings' maximum force. Let go of the enable and the fingers
                   stop where they are; if the console dies, the robot node's watchdog stops them
                   within 0.2 s. r ends the grasp (the fingers open).

Keys (--input keyboard; a terminal has no key release, so the enable toggles):
  up / k     squeeze the grip a step        down / j   open it a step      o   open fully
  e          enable on / off (dead-man)     g          grasp at the force  r   release
  s          stop (enable off)              n          next object         q   quit
  + / -      grasp force +/- 1 N            ctrl+c     quit
  l          label the grasp: what the object is (below)
With --input gamepad, display or sim the device drives the grip, the enable and its buttons;
g r s n q, + - and l still work from the keyboard.

Labelling: l opens a line for the grasp shown (after n, the last one). Type the object's name
from the catalogue (--objects; the right arrow takes the suggestion), or a name with a Shore
reading ("blue gel shore 00 60", "pad shore A 40": converted to E by Gent's relation) or the
maker's modulus ("cork mat 12 MPa"); enter sends it on the bus, where `teleop record` logs it
and `teleop export` takes it as the grasp's label; escape closes the line. After the session,
`teleop label LOG --csv FILE` labels grasps from a CSV instead.

A session: g (or hold the enable and squeeze), watch the force, the estimate and what the
display renders, r to release, n for the next object, q to quit.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "The operator console: a terminal UI (works over SSH and in tmux, keyboard only) that drives the "
        "gripper from an operator input device and shows whether the robot node, estimator and display are "
        "alive, the grasp's phase, force and width, the live estimate with its interval and state, what the "
        "display renders, and the robot's notices (refused commands, the watchdog)."
    )
    parser.epilog = HELP
    parser.formatter_class = _HelpFormatter
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML ([gripper] width and maximum force, [operator] input device, [bus])")
    parser.add_argument("--input", choices=sorted(INPUT_BACKENDS), default=None,
                        help="operator input device (default: [operator] input of the settings)")
    parser.add_argument("--force", type=float, default=None, metavar="N",
                        help="discrete grasp force, newtons, at most the settings' gripper.target_force_n "
                             "(default: gripper.target_force_n)")
    add_endpoint_arguments(parser, "robot_pub", "estimate_pub", "command", "display_pub")
    parser.add_argument("--objects", metavar="PATH", default=str(default_catalogue_path()),
                        help="object catalogue (.toml or .csv) whose names a label may give (the l key)")
    parser.add_argument("--headless", action="store_true",
                        help="no screen: run the loop and print one line per action (the sim input, scripts; "
                             "any input but the keyboard, whose keys the screen reads)")
    parser.add_argument("--duration-s", type=positive_number, default=None, metavar="S",
                        help="stop after S seconds (default: until quit, Ctrl-C or SIGTERM)")
    parser.add_argument("--json", action="store_true",
                        help="on exit print one JSON object (follows_sent, commands_sent, last grasp, labels given, problem) "
                             "as the last stdout line")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Keeps the epilog's layout; appends defaults unless the option says its own."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.required or action.default is None or action.nargs == 0 or "(default" in text:
            return text
        return super()._get_help_string(action)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text.strip():
            return textwrap.indent(text, indent)
        return argparse.HelpFormatter._fill_text(self, text, width, indent)


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    bus = bus_from_args(settings, args)
    name = args.input or operator_settings(settings).input
    limit = settings.gripper.target_force_n
    if args.force is not None and not 0 < args.force <= limit:
        raise SettingsError(f"--force {args.force:g}: expected a force in (0, {limit:g}] N, the settings' maximum "
                            "grasp force (gripper.target_force_n)")
    if args.headless and input_class(name).needs_console:
        raise SettingsError(f"--input {name} reads the console's own keys, which --headless has none of: drop "
                            "--headless, or drive it headless from another input (sim, gamepad, display)")
    if not args.headless and not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise SettingsError("haptics operate needs a terminal for its screen; run it in one (or in tmux), "
                            "or pass --headless")
    catalogue = () if args.headless else load_catalogue(args.objects)
    # held before the link connects: a refused handshake is said then, and must reach the notices
    holding = contextlib.nullcontext() if args.headless else _held_log()
    with holding as held, make_input(name, settings) as device, OperatorLink.from_settings(bus) as link:
        loop = OperatorLoop(link, device, settings, force_n=args.force)
        if held is None:
            status = _run_headless(loop, name, duration_s=args.duration_s)
        else:
            status = _run_console(loop, name, device, held, duration_s=args.duration_s, catalogue=catalogue,
                                  catalogue_name=args.objects)
    print(f"operator: {status.follows_sent} follow and {status.commands_sent} command message(s) sent"
          + (f"; last problem: {status.problem}" if status.problem else ""), file=sys.stderr)
    if args.json:
        print(json.dumps(summary(name, status), allow_nan=False))
    return 0


def summary(name: str, status: LoopStatus) -> dict[str, Any]:
    """What ``--json`` prints on exit: the messages sent, the last grasp (the one shown, else the last
    one ``next`` cleared: its id, phase and final estimate), the labels given and the last problem."""
    view = status.view
    if view.grasp_id is None and status.last_ended is not None:
        view = status.last_ended
    return {"input": name, "follows_sent": status.follows_sent, "commands_sent": status.commands_sent,
            "grasp_id": view.grasp_id, "phase": view.phase,
            "estimate": None if view.estimate is None else view.estimate.as_dict(),
            "labels": {grasp_id: body.as_dict() for grasp_id, body in status.labels.items()},
            "problem": status.problem or None}


def _run_console(loop: OperatorLoop, name: str, device: object, held: _HeldLog, *, duration_s: float | None,
                 catalogue: tuple = (), catalogue_name: str = "the catalogue") -> LoopStatus:
    from haptics.console import OperatorConsole

    keyboard = device if getattr(device, "name", "") == "keyboard" else None
    app = OperatorConsole(loop, input_name=name, keyboard=keyboard, duration_s=duration_s, catalogue=catalogue,
                          catalogue_name=catalogue_name)
    held.attach(app)
    try:
        with _sigterm_quits(app):
            app.run(mouse=False)
    finally:
        if app.stop_loop():  # the loop's sockets are this thread's only once its thread has ended
            loop.finish()
    return loop.status


@contextlib.contextmanager
def _held_log() -> Iterator[_HeldLog]:
    """Log lines written to the terminal would tear the screen: the root logger's records are held
    from here on (the screen shows the last warning once :meth:`_HeldLog.attach` gives it one), and
    printed when the block ends."""
    held = _HeldLog()
    root = logging.getLogger()
    handlers = root.handlers[:]
    for handler in handlers:
        root.removeHandler(handler)
    root.addHandler(held)
    try:
        yield held
    finally:
        root.removeHandler(held)
        for handler in handlers:
            root.addHandler(handler)
        for record in held.records:
            root.handle(record)


@contextlib.contextmanager
def _sigterm_quits(app: Any) -> Iterator[None]:
    """SIGTERM and SIGHUP (the terminal hung up: an SSH drop, tmux kill-session; unless ignored, as
    under ``nohup``) quit the screen as ``q`` does (the loop lets the enable go and releases its grasp,
    the terminal leaves the screen, the summary is printed) instead of killing the process mid-screen
    with the fingers squeezing."""
    def on_sigterm(signum: int, frame: Any) -> None:  # noqa: ARG001
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:  # the screen is not up (yet, or any more): stop as Ctrl-C would, saying why
            raise Terminated(signum) from None
        # The handler interrupts the screen's own thread: its action runs on the screen's loop.
        running.call_soon_threadsafe(app.action_quit_console)

    with on_stop_signals(on_sigterm):
        yield


class _HeldLog(logging.Handler):
    """Keeps the last :data:`HELD_LOG_RECORDS` log records while the screen runs, and shows the last
    warning on ``app``'s screen (``log_note``): a refused handshake must not wait for the quit. One
    logged before the screen exists (as the sockets connect) is shown once it is attached."""

    def __init__(self, app: Any = None) -> None:
        super().__init__()
        self.app = app
        self.note = ""  # the last warning
        self.records: collections.deque[logging.LogRecord] = collections.deque(maxlen=HELD_LOG_RECORDS)

    def attach(self, app: Any) -> None:
        """Show the last warning so far, and each one after, on ``app``'s screen."""
        self.app = app
        app.log_note = self.note

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)
        if record.levelno >= logging.WARNING:
            self.note = f"{record.levelname.lower()}: {record.getMessage()}"
            if self.app is not None:
                self.app.log_note = self.note


def _run_headless(loop: OperatorLoop, name: str, *, duration_s: float | None) -> LoopStatus:
    print(f"operator: input {name}, headless; commands on {loop.link.publisher.endpoint}", file=sys.stderr)
    shown = ""

    def show(status: LoopStatus) -> None:
        nonlocal shown
        line = _headless_line(status)
        if line != shown:
            print(line, flush=True)
            shown = line

    with StopSignals() as signals:
        return loop.run(signals.stop, duration_s=duration_s, on_status=show)


def _headless_line(status: LoopStatus) -> str:
    from haptics.console import estimate_line

    view = status.view
    return (f"{status.mode:<8} grasp {view.grasp_id or '-'} {view.phase:<7} | {estimate_line(view.estimate)}"
            + (f" | {status.last_action}" if status.last_action else ""))
