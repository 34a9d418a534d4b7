"""From the operator's hand to the fingers, and from contact to feeling the object right.

Usage::

    .venv/bin/python benchmarks/bench_operator.py [--seconds 10] [--scene default] [--json]

1. **Input to gripper command** (loopback): the operator's loop (:class:`haptics.operator_loop.OperatorLoop`)
   reads a scripted input device whose grip sweeps the fingers' free travel at the follow rate, and
   sends ``follow`` over ZeroMQ on loopback to a robot node on the simulated rig in another thread;
   the figure is the time from the input reading (its ``t_s``) to the node's call of
   ``gripper.follow`` with that reading's target width, matched by width. The sweep starts once the
   loop hears the robot node, so all of ``--seconds`` drives it. Printed as p50 and p99, in ms and
   in frame baselines (:class:`scriptkit.Baseline`, timed before and after this part); a run that
   matched no command is an error.
2. **Contact to the display within a factor 2**, on operator-driven grasps: ``teleop demo
   --operator sim`` on ``--scene`` (its processes on loopback; the simulated operator squeezes every
   object), and per grasp the time from the load cell first reading the contact force until every
   later display report of the grasp lies within a factor 2 of the label clipped to the display's
   range (``t_felt_within_2x_s`` of its JSON). Printed as median and 90th percentile over the grasps
   that settled, with the count that never did. The online estimator of the paper's authors
   converges in 0.24 s.

Both on this host's monotonic clock. Run on an otherwise idle machine: the figures move with its load.
Ctrl-C or SIGTERM stop the demo of part 2 too, and remove its files.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from scriptkit import Baseline, BenchmarkError, run_child, run_script

from haptics.inputs.base import OperatorInput
from haptics.operator_grasps import unreachable
from haptics.operator_link import OperatorLink
from haptics.operator_loop import OperatorLoop
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.clikit import positive_number
from teleop.node import COMMAND_TOPICS, RobotNode
from teleop.operator import grip_to_width_m
from teleop.scene import load_scene

SWEEP_GRIP = (0.0, 0.15)  # the fingers move through free air, well before any scene object
LET_GO_SHARE = 0.05  # of each sweep, at its start, with the enable let go
HEAR_ROBOT_S = 10.0  # the node's first heartbeat, however loaded the machine


class SweepInput:
    """A scripted operator input: the grip sweeping SWEEP_GRIP back and forth, the enable held but at
    the start of each sweep; every reading's time and target width are kept.

    The loop reads it only once the robot node is heard (``waits_for_robot``), and its sweep starts at
    that first reading with the enable let go: the loop drives only an enable let go and held again
    once the node is heard, and one held from before would drive nothing until the next sweep."""

    waits_for_robot = True

    def __init__(self, max_width_m: float, period_s: float = 2.0):
        self.max_width_m = max_width_m
        self.period_s = period_s
        self.readings: list[tuple[float, float]] = []  # (t_s, target width m)
        self._start: float | None = None  # the first reading's time

    def read(self, *, timeout_s: float = 0.0) -> OperatorInput:
        now = time.monotonic()
        if self._start is None:
            self._start = now
        phase = ((now - self._start) / self.period_s) % 1.0
        grip = SWEEP_GRIP[0] + (SWEEP_GRIP[1] - SWEEP_GRIP[0]) * (1.0 - abs(2.0 * phase - 1.0))
        self.readings.append((now, grip_to_width_m(grip, max_width_m=self.max_width_m)))
        return OperatorInput(t_s=now, grip=grip, enable=phase >= LET_GO_SHARE)

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None = None) -> None:
        pass


def _hear_the_robot(link: OperatorLink, *, timeout_s: float) -> None:
    """Wait until ``link`` hears the robot node alive and alone: the loop's ``duration_s`` runs from
    its start, so on a loaded machine a node heard late would leave part of ``--seconds`` undriven."""
    deadline = time.monotonic() + timeout_s
    while not (link.view.alive("robot node") and not unreachable(link.view)):
        if time.monotonic() > deadline:
            raise BenchmarkError(f"the robot node was not heard within {timeout_s:g} s: nothing to time")
        link.poll(timeout_s=0.05)


def input_to_command(scene_name: str, seconds: float) -> dict[str, float | int | None]:
    """Part 1 (module docstring): p50 and p99 (ms) of input reading -> gripper.follow.

    Raises BenchmarkError when no command was matched to a reading: there is no figure to give."""
    scene = load_scene(scene_name)
    settings = scene.settings
    robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    commands = Subscriber(operator.endpoint, COMMAND_TOPICS)
    node = RobotNode(settings, publisher=robot, commands=commands, scene=scene).connect()
    calls: list[tuple[float, float]] = []
    follow = node.gripper.follow

    def timed_follow(width_m: float, **kwargs) -> None:
        calls.append((time.monotonic(), float(width_m)))
        follow(width_m, **kwargs)

    node.gripper.follow = timed_follow
    stop = threading.Event()
    thread = threading.Thread(target=node.run, args=(stop,), daemon=True)
    thread.start()
    device = SweepInput(settings.gripper.max_width_m)
    link = OperatorLink(publisher=operator,
                        subscriber=Subscriber(robot.endpoint, ("grasp_event", "robot_state", "robot_notice")),
                        heartbeat_s=settings.bus.heartbeat_s)
    try:
        operator.wait_for_subscriber(*COMMAND_TOPICS, timeout_s=5.0)
        _hear_the_robot(link, timeout_s=HEAR_ROBOT_S)
        OperatorLoop(link, device, settings).run(duration_s=seconds)
    finally:
        stop.set()
        thread.join(timeout=5.0)
        node.close()
        for sock in (link, robot, commands):
            sock.close()
    sent = dict((round(w, 9), t) for t, w in reversed(device.readings))  # a width's first reading
    latencies = [t_call - sent[round(w, 9)] for t_call, w in calls if round(w, 9) in sent]
    if not latencies:
        raise BenchmarkError(f"--seconds {seconds:g}: no gripper command matched to an input reading "
                             f"({len(calls)} commands, {len(device.readings)} readings): nothing to time")
    ms = np.array(latencies) * 1e3
    return {"commands": len(calls), "matched": len(latencies),
            "p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99))}


def contact_to_felt(scene_name: str) -> dict[str, float | int | None]:
    """Part 2 (module docstring): median and p90 (s) of contact -> display within 2x, from the demo."""
    with tempfile.TemporaryDirectory() as out:
        line = [sys.executable, "-c", "import sys; from teleop.cli import main; sys.exit(main())", "demo",
                "--operator", "sim", "--scene", scene_name,
                "--json", "--no-view", "--out", str(Path(out) / "demo")]
        done = run_child(line)
    if done.returncode != 0:
        raise SystemExit(f"teleop demo failed ({done.returncode}):\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    times = [g["t_felt_within_2x_s"] for g in result["grasps"]]
    settled = np.array([t for t in times if t is not None])
    return {"grasps": len(times), "settled": int(settled.size),
            "median_s": float(np.median(settled)) if settled.size else None,
            "p90_s": float(np.percentile(settled, 90)) if settled.size else None}


def _fmt(value: float | None, unit: str, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f} {unit}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=positive_number, default=10.0, help="how long the operator's loop drives (part 1)")
    parser.add_argument("--scene", default="default", help="scene of the operator-driven grasps (part 2)")
    parser.add_argument("--json", action="store_true", help="print all figures as one JSON object last")
    return run_script(parser, measure)


def measure(args: argparse.Namespace) -> None:
    logging.getLogger("teleop.node").setLevel(logging.ERROR)  # "stopping during grasp": the sweep's end
    baseline = Baseline()
    baseline.time()
    command = input_to_command(args.scene, args.seconds)
    baseline.time()
    command |= {f"{q}_in_baselines": baseline.ratio(command[f"{q}_ms"]) for q in ("p50", "p99")}
    print(baseline.line())
    print(f"operator input -> gripper command (loopback, {command['matched']} of {command['commands']} "
          f"commands matched): p50 {command['p50_ms']:.1f} ms ({command['p50_in_baselines']:.2f} bl), "
          f"p99 {command['p99_ms']:.1f} ms ({command['p99_in_baselines']:.2f} bl)")
    felt = contact_to_felt(args.scene)
    print(f"contact -> display stays within a factor 2 ({felt['settled']} of {felt['grasps']} operator grasps "
          f"settled): median {_fmt(felt['median_s'], 's', 2)}, p90 {_fmt(felt['p90_s'], 's', 2)} "
          "(the paper's online estimator: 0.24 s)")
    if args.json:
        print(json.dumps({**baseline.figures(), "input_to_command": command, "contact_to_felt_within_2x": felt}))


if __name__ == "__main__":
    raise SystemExit(main())
