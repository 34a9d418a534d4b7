"""``teleop demo``: the live system on simulated hardware, one grasp per scene object, with a closing table.

The live system (:class:`~teleop.system.live_system.LiveSystem`: robot node, estimator, renderer
and recorder, separate processes on loopback) runs with this process as its operator. A child that
exits early stops the demo with the tail of its log, except a recorder whose recording a write error
stopped (a full disk): the demo says so and carries on, and its closing output calls the session log
partial; SIGTERM and SIGHUP (its terminal closed) stop the demo as Ctrl-C does.

The estimator's sensor needs a colour-to-gradient calibration. When the settings name none (or
the file is missing) one is fitted at start on simulated ball presses of that sensor
(:func:`~teleop.system.live_system.simulated_calibration`, a couple of seconds) and the demo says so.

Results per grasp: the true E (catalogue), the final estimate, its state and interval, what the
display rendered for it (renderer report: the fraction of the display's range, 1 = rigid, i.e. at
or beyond the sensor's resolution limit, or unknown: the display goes free), the signed offset in
decades (of the estimate; the table shows the rendering's), the time from contact to the first
estimate that is not a refusal (estimator report), and the latency from the last loading frame's capture to the display report that showed the final
estimate (renderer report). All on this host's monotonic clock; and the learned model that made the
final estimate (``model``: its :func:`~estimator.inference.infer.model_id`, none for an analytical
estimate); and for a grasp the robot node cut short, the robot_notice that ended it (``ended_by``:
its watchdog stopped the fingers, or a gripper command failed). The live lines and the closing table
are in :mod:`teleop.system.demo_table`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TextIO

from teleop.bus.wire import Message
from teleop.catalogue import ObjectSpec
from teleop.clikit import file_in_the_way, help_literal
from teleop.errors import SettingsError
from teleop.scene import SCENE_DIR, Scene, load_scene, scene_path
from teleop.session.foxglove_live import add_foxglove_argument
from teleop.settings import Settings, default_settings_path, load_settings
from teleop.system.demo_table import LiveView, closing_table, felt_summary, models_answered
from teleop.system.live_system import (
    CALIBRATION_PRESSES,
    LiveSystem,
    configured_calibration,
    simulated_calibration,
)
from teleop.system.outcome import GraspOutcome

__all__ = [
    "LiveView",
    "add_arguments",
    "add_run_arguments",
    "closing_table",
    "prepare_run",
    "run",
    "run_grasps",
    "scene_plan",
]

RUN_NAME_TRIES = 100  # default run folders tried in one second: far more runs than are started at once


def scene_plan(scene_name: str, n_grasps: int | None = None) -> list[tuple[int, ObjectSpec]]:
    """(object index, object) of each grasp: the scene's objects repeated ``grasps_per_object``
    times, cycled to ``n_grasps`` when given."""
    scene = load_scene(scene_name)
    objects = [o for o in scene.objects for _ in range(scene.grasps_per_object)]
    count = len(objects) if n_grasps is None else n_grasps
    return [(i % len(objects), objects[i % len(objects)]) for i in range(count)]


def check_objects_fit(scene: Scene, settings: Settings) -> None:
    """Raise SettingsError naming the scene's objects too wide for the open gripper: the simulated
    node would fail each of their grasps, seen only in its log."""
    # The node's own test (teleop.sim.shapes.draw_pose): some orientation narrower than the margin.
    from teleop.sim.shapes import FIT_MARGIN, narrowest_width, object_size

    opening = settings.gripper.max_width_m
    widths = {obj.name: narrowest_width(obj, object_size(obj)) for obj in scene.objects}
    wide = [f"{name!r} ({width:.3g} m)" for name, width in widths.items() if width >= FIT_MARGIN * opening]
    if wide:
        raise SettingsError(
            f"scene {scene.name!r}: objects {', '.join(wide)} are, at their narrowest, wider than fingers open to "
            f"gripper.max_width_m = {opening:g} m take (less {1 - FIT_MARGIN:.0%} to spare: under "
            f"{FIT_MARGIN * opening:.3g} m): raise gripper.max_width_m or leave them out of the scene")


def _check_out(run_dir: Path) -> None:
    """Make the folder ``--out`` names, refusing one that holds an earlier run or is in the way."""
    earlier = sorted(p.name for p in run_dir.glob("*") if p.suffix in (".log", ".mcap")) if run_dir.is_dir() else []
    if earlier:  # the processes' logs would be replaced before the recorder refused the session log
        raise SettingsError(f"--out {run_dir} holds an earlier run ({', '.join(earlier[:3])}): choose another folder")
    blocker = file_in_the_way(run_dir)
    if blocker is not None:
        raise SettingsError(f"--out {run_dir}: {blocker} is not a directory; expected a folder for the run "
                            "(new or empty)")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SettingsError(f"--out {run_dir}: cannot make the folder ({exc.strerror or exc})") from exc


def _new_run_dir(base: Path) -> Path:
    """A folder made anew (never one another run made) named ``base``, or ``base-2``, ``base-3``, ...
    when other runs started in the same second took those first."""
    try:
        base.parent.mkdir(parents=True, exist_ok=True)
        for n in range(1, RUN_NAME_TRIES + 1):
            run_dir = base if n == 1 else base.with_name(f"{base.name}-{n}")
            with contextlib.suppress(FileExistsError):
                run_dir.mkdir()  # exclusive: two runs never share a folder
                return run_dir
    except OSError as exc:
        raise SettingsError(f"cannot make the run folder {base} ({exc.strerror or exc}): pass --out DIR") from exc
    raise SettingsError(f"{base} and {base.name}-2 .. -{RUN_NAME_TRIES} exist already: pass --out DIR")


def prepare_run(args: argparse.Namespace, *, prefix: str, out: TextIO) -> tuple[Path, Path]:
    """The run directory (made) and the calibration to use (fitted there when none is configured).

    Raises SettingsError when the settings are not the scene's, name hardware backends (the live
    system runs here on the simulated robot), or open the gripper too little for the scene's objects.
    """
    from teleop.session.recorder import session_source

    settings = load_settings(args.settings)
    scene = load_scene(args.scene)
    if scene.settings != settings:
        where = scene_path(args.scene)
        raise SettingsError(
            f"scene {args.scene!r} names other settings than --settings {args.settings}: {where} names "
            f"{scene.settings_path} (its `settings` key; the shipped settings without one): pass --settings "
            f"{scene.settings_path}, or to run the scene on {args.settings}, set settings = "
            f"\"{Path(args.settings).absolute()}\" in {where} (or a copy of it)")
    if session_source(settings) != "simulated":
        raise SettingsError(f"{args.settings} names hardware backends; {prefix} runs on the simulated robot: "
                            "use settings whose gripper, load cell and cameras are 'sim'")
    check_objects_fit(scene, settings)
    if args.out:
        run_dir = Path(args.out)
        _check_out(run_dir)
    else:
        run_dir = _new_run_dir(Path("runs") / f"{prefix}-{datetime.now(UTC):%Y%m%d-%H%M%S}")
    calibration = configured_calibration(settings)
    if calibration is None:
        started = time.monotonic()
        calibration = simulated_calibration(settings, run_dir)
        print(f"no calibration file for the {settings.sensing.finger} sensor in the settings: fitted one on "
              f"{CALIBRATION_PRESSES} simulated ball presses in {time.monotonic() - started:.1f} s -> {calibration}",
              file=out)
    return run_dir, calibration


# --------------------------------------------------------------------------- grasps


def run_grasps(system: LiveSystem, plan: Sequence[tuple[int, ObjectSpec]], view: LiveView, prefix: str, *,
               on_message: Callable[[Message], None] | None = None) -> Iterator[GraspOutcome]:
    """Run the grasps of ``plan`` one after another, showing each on ``view``."""
    for number, (index, obj) in enumerate(plan, start=1):
        outcome = system.grasp(f"{prefix}-{number:03d}", index, obj, on_message=on_message,
                               on_update=lambda o, n=number: view.update(n, o))
        view.finish(number, outcome)
        yield outcome


def operated_grasps(system: LiveSystem, plan: Sequence[tuple[int, ObjectSpec]], view: LiveView,
                    settings: Settings) -> Iterator[GraspOutcome]:
    """The simulated operator grasps the objects of ``plan`` in order (the node takes the scene's
    objects in turn), each shown on ``view`` with how the operator squeezed it."""
    from teleop.system.seat import SimulatedSeat

    with SimulatedSeat(system, settings, grasps=len(plan)) as seat:
        for number, (_, obj) in enumerate(plan, start=1):
            def update(outcome: GraspOutcome, n: int = number) -> None:
                seat.check()
                if outcome.started and not outcome.operator_style:
                    outcome.operator_style = seat.style()
                view.update(n, outcome)

            outcome = system.operated_grasp(obj, on_update=update)
            view.finish(number, outcome)
            yield outcome


# --------------------------------------------------------------------------- command


def add_run_arguments(parser: argparse.ArgumentParser, *, default_scene: str) -> None:
    """Options shared by ``demo`` and ``bench-latency``."""
    parser.add_argument("--scene", default=default_scene, metavar="NAME",
                        help=f"scene to grasp: a name under {help_literal(SCENE_DIR)} (default, quick) or a .toml path")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML every process reads, the one the scene names (the shipped "
                             "scenes name the shipped settings, the default); its bus endpoints are replaced by "
                             "free loopback ports")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="run directory for the processes' logs and reports and the session log "
                             "(default: runs/<command>-<UTC time>)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object on stdout, alone: the text goes to stderr")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Run the live system on simulated hardware (robot node, estimator service, haptic renderer on a "
        "simulated display, session recorder: separate processes on loopback), grasp every object of a scene "
        "once, show each grasp live, then print a closing table (grasp style, true E, final estimate and state, "
        "what the display rendered: rigid, unknown, or the fraction of its range and the modulus it stands for; "
        "the felt error in decades, against the label on the display's range, so that an object stiffer than the "
        "sensor resolves is right when rendered rigid; time to the first estimate; how soon after contact the display "
        "stayed within a factor 2; a scripted grasp's latency to the display report; for a grasp the robot node "
        "cut short, a 'cut: EVENT' note and a line with the notice's reason), what was felt, and the log's path."
    )
    add_run_arguments(parser, default_scene="default")
    parser.add_argument("--operator", choices=("sim", "script"), default="sim",
                        help="who grasps: 'sim' (default), a simulated person in the operator's seat driving the "
                             "fingers leader-follower, closing at a speed of its own, pausing, backing off and "
                             "squeezing again, as haptics operate --input sim does; 'script', the paper's grasp "
                             "commanded at once (close at the settings' speed to a force, hold, release)")
    parser.add_argument("--model", metavar="DIR", default=None,
                        help="learned model folder (model.onnx and metadata.json) the estimator serves, or 'none' "
                             "for analytical estimates only (default: [estimator] model_path of the settings, else "
                             "the shipped default model); each grasp's JSON and the closing table name the model "
                             "that answered")
    parser.add_argument("--no-view", action="store_true", help="no live status lines, only the closing table")
    add_foxglove_argument(parser, what="the live system's bus (tactile video, force, width, estimates)")


def checked_model(option: str | None) -> str | None:
    """``--model`` as the estimator child gets it: None (the settings' model) or "none" as given,
    else the folder's absolute path once it is seen to hold a model.

    Raises
    ------
    ModelError
        The folder does not exist, lacks a model file (named) or holds metadata the estimator would
        refuse, before any process starts.
    """
    from estimator.inference.infer import ModelMetadata, model_id, read_metadata

    if option is None or option == "none":
        return option
    path = Path(option).absolute()
    path = path.parent if path.suffix == ".onnx" else path
    model_id(path)
    meta_path, data = read_metadata(path)
    ModelMetadata.from_json(data, str(meta_path))
    return str(path)


def run(args: argparse.Namespace) -> int:
    started = time.monotonic()
    scene = load_scene(args.scene)
    plan = scene_plan(args.scene)
    model = checked_model(args.model)
    text = sys.stderr if args.json else sys.stdout  # under --json stdout is the JSON alone
    run_dir, calibration = prepare_run(args, prefix="demo", out=text)
    view = LiveView(text, len(plan), enabled=not args.no_view)
    system = LiveSystem(Path(args.settings), args.scene, run_dir, calibration, foxglove=args.foxglove, model=model)
    with system:
        if args.foxglove is not None:  # once the recorder is up: serving it, not failing to bind its port
            host, port = args.foxglove
            print(f"Foxglove live view: ws://{host}:{port}" if port else
                  f"Foxglove live view: the port the recorder chose, in {run_dir / 'recorder.log'}", file=sys.stderr)
        print(f"live system up ({', '.join(f'{n} {c.process.pid}' for n, c in system.children.items())}); "
              f"logs in {run_dir}", file=sys.stderr)
        if args.operator == "sim":
            outcomes = list(operated_grasps(system, plan, view, load_settings(args.settings)))
        else:
            outcomes = list(run_grasps(system, plan, view, prefix=scene.name))
    print(closing_table(outcomes), file=text)
    partial = "" if system.recording_stopped is None else f" (partial: recording stopped: {system.recording_stopped})"
    print(f"session log: {system.session_log}{partial}", file=text)
    if args.json:
        print(json.dumps({"scene": scene.name, "operator": args.operator, "grasps": [o.to_json() for o in outcomes],
                          "models": models_answered(outcomes), "summary": felt_summary(outcomes),
                          "session_log": str(system.session_log), "recording_stopped": system.recording_stopped,
                          "run_dir": str(run_dir),
                          "wall_s": time.monotonic() - started}, allow_nan=False))
    return 0
