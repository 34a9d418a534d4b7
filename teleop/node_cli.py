"""``teleop node``: run the robot node (:mod:`teleop.node`) on the bus until Ctrl-C, SIGTERM or SIGHUP.

With ``--foxglove`` it also serves what it publishes live to Foxglove
(:class:`~teleop.session.foxglove_live.LiveTap`).
"""

from __future__ import annotations

import argparse
import json
import sys

from teleop.bus.pubsub import Publisher, Subscriber
from teleop.clikit import help_literal, positive_number
from teleop.live import StopSignals, add_endpoint_arguments, bus_from_args
from teleop.node import COMMAND_TOPICS, RobotNode
from teleop.scene import SCENE_DIR, load_scene
from teleop.session.foxglove_live import LiveTap, add_foxglove_argument
from teleop.settings import default_settings_path, load_settings

# How long a robot data send waits for a subscriber whose queue (a minute of the stream) is full
# before skipping it: the node's loop stands still meanwhile, once per stall.
STALLED_AFTER_S = 0.1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Run the robot node: read the gripper, tactile cameras and load cell and publish frames, forces, "
        "widths and grasp events on the bus; carry out operator commands (start_grasp, stop, release) and "
        "follow the operator's target width (follow messages, while enable is held; the fingers stop when "
        "none came for 0.2 s); publish robot_state and robot_notice. With the simulated backends a "
        "start_grasp simulates a grasp of the scene's next object and replays it in real time, and a "
        "follow grasp simulates the next object live. Stops on Ctrl-C or SIGTERM."
    )
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (device backends, sensors, gripper, simulation, bus)")
    parser.add_argument("--scene", default="default", metavar="NAME",
                        help=f"scene whose objects simulated grasps take (a name under {help_literal(SCENE_DIR)} or a "
                             ".toml path); its settings file is not read, --settings is used")
    add_endpoint_arguments(parser, "robot_pub", "command")
    parser.add_argument("--duration-s", type=positive_number, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)")
    add_foxglove_argument(parser, what="what the node publishes (frames, forces, widths, grasp events)")
    parser.add_argument("--json", action="store_true",
                        help="on exit print one JSON object (grasps, frames, force_batches, width_batches, "
                             "bad_commands, device_errors, watchdogs, frames_dropped (by the cameras: captured, "
                             "never read); wire: what its subscribers refused on the wire, by reason, and their "
                             "sequence gaps) as the last stdout line")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    bus = bus_from_args(settings, args)
    scene = load_scene(args.scene)
    # The signals first: they are handled until the node and its sockets have closed, so a second one
    # cannot cut that closing short (StopSignals ignores it).
    with (
        StopSignals() as signals,
        # skip_stalled: one observer that stops reading (a recorder stopped with Ctrl-Z) must not stop the robot
        Publisher.from_settings(bus, bus.robot_pub, lossless=True, source="robot", skip_stalled=True,
                                send_timeout_s=STALLED_AFTER_S) as publisher,
        Subscriber.from_settings(bus, bus.command, COMMAND_TOPICS) as commands,
        RobotNode(settings, publisher=publisher, commands=commands, scene=scene) as node,
        LiveTap(publisher.endpoint, args.foxglove, bus=bus, name="teleop node",
                fingers=[s.finger for s in settings.sensors]),
    ):
        print(f"robot node: {'simulated' if node.simulated else 'hardware'} devices; data on "
              f"{publisher.endpoint}, commands from {bus.command}", file=sys.stderr)
        stats = node.run(signals.stop, duration_s=args.duration_s)
    print(f"robot node: {stats.grasps} grasps, {stats.frames} frames published", file=sys.stderr)
    if args.json:
        print(json.dumps({**stats.as_dict(), "wire": node.wire_stats()}))
    return 0
