"""Fault injection on the bus: processes killed and restarted, slow subscribers, zero timeouts.

Faults tested elsewhere (not repeated here):
* recorder killed with SIGKILL, log salvaged by ``teleop recover``:
  tests/teleop/session/test_recover.py::test_a_recorder_killed_with_sigkill_loses_at_most_its_open_chunk;
* disk full while logging:
  tests/teleop/session/test_recorder.py::test_disk_full_stops_recording_cleanly_while_the_bus_carries_on;
* HID display unplugged and replugged:
  tests/haptics/test_hid_and_backends.py::test_an_unplug_wraps_oserror_and_disconnects and
  ::test_replug_under_a_new_path_is_found_again.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from haptics.devices.sim import SimulatedDisplay
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.errors import BusTimeoutError
from teleop.settings import load_settings
from teleop.soak import rss_bytes
from teleop.system.live_system import free_ports


def test_recv_with_zero_timeout_takes_what_is_queued_without_waiting():
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub, Subscriber(pub.endpoint) as sub:
        pub.wait_for_subscriber("force")
        started = time.monotonic()
        assert sub.recv(timeout_s=0) is None  # nothing sent yet
        assert time.monotonic() - started < 1.0  # a recv that waited would wait for ever
        for i in range(3):
            pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[1.0])
        # Look without waiting until all three are taken, however slowly they arrive; then nothing is left.
        got = []
        deadline = time.monotonic() + 5.0
        while len(got) < 3 and time.monotonic() < deadline:
            looked = time.monotonic()
            message = sub.recv(timeout_s=0)
            assert time.monotonic() - looked < 1.0  # a look, not a wait
            if message is None:
                time.sleep(0.01)
            else:
                got.append(message)
        got.append(sub.recv(timeout_s=0))
    assert [m.seq for m in got[:3]] == [0, 1, 2] and got[3] is None


# --------------------------------------------------------------------------- processes killed and restarted

_PEER = textwrap.dedent("""
    import sys, time
    from teleop.bus.pubsub import Publisher
    endpoint, kind = sys.argv[1], sys.argv[2]
    with Publisher(endpoint, lossless=kind == "force", source=sys.argv[3], heartbeat_s=0.1) as pub:
        pub.wait_for_subscriber(kind, timeout_s=10.0)
        n = 0
        while True:
            pub.heartbeat_if_due()
            t = time.monotonic()
            if kind == "estimate":
                pub.send("estimate", t_capture_s=t, grasp_id="g1", method="series", E_pa=1e5 * (1 + n % 2),
                         interval_pa=[5e4, 4e5], state="ok", reason="peer", provisional=True, latency_s=0.0)
            else:
                pub.send("force", t_capture_s=t, grasp_id=None, t_s=[t], value_n=[float(n)])
            n += 1
            time.sleep(0.02)
""")


def start_peer(endpoint: str, kind: str, source: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", _PEER, endpoint, kind, source], stdin=subprocess.DEVNULL)


def kill(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=10)


@pytest.mark.slow
def test_estimator_killed_and_restarted_renderer_lets_go_and_resumes():
    """The estimator's endpoint goes silent mid-grasp (SIGKILL) and comes back on the same port."""
    rendering = display_settings(load_settings())
    endpoint = f"tcp://127.0.0.1:{free_ports(1)[0]}"
    subscriber = Subscriber(endpoint, ("estimate", "grasp_event"), conflate=True)
    service = RendererService(HapticRenderer(SimulatedDisplay(), rendering), subscriber=subscriber,
                              tick_s=0.005)
    peer = start_peer(endpoint, "estimate", "estimator")
    try:
        def run_until(done, timeout_s):
            deadline = time.monotonic() + timeout_s
            while not done():
                assert time.monotonic() < deadline, "timed out"
                service.step()

        run_until(lambda: service.stats.estimates >= 10, 15.0)
        assert service.renderer.phase == "active" and service.renderer.percept.stiffness > 0
        killed = time.monotonic()
        kill(peer)
        # Unheard for three heartbeat periods (0.3 s), no one vouches for the value: the display goes free.
        run_until(lambda: service.renderer.phase == "idle", 3.0)
        assert time.monotonic() - killed >= 0.15  # not before the estimator could be judged dead
        received = service.stats.estimates  # with any the dead peer had queued
        run_until(lambda: time.monotonic() - killed > rendering.stale_after_s + 0.5, 5.0)
        assert service.renderer.phase == "idle" and service.renderer.command.level == 0
        assert service.stats.estimates == received
        peer = start_peer(endpoint, "estimate", "estimator")
        restarted = time.monotonic()
        run_until(lambda: service.stats.estimates > received, 15.0)  # process start (imports) + reconnect
        first = time.monotonic()
        # Active again at once: the first fresh estimate's step does it (milliseconds when idle). 2 s
        # rather than 1 s allows only for a loaded machine (two test workers on two cores) descheduling us.
        run_until(lambda: service.renderer.phase == "active", 2.0)
        assert not service.renderer.command.stale
        assert time.monotonic() - first < 2.0, f"resumed {time.monotonic() - restarted:.2f} s after the restart"
    finally:
        kill(peer)
        subscriber.close()


@pytest.mark.slow
def test_robot_node_restarted_subscriber_reconnects_and_reports_the_restart(caplog):
    endpoint = f"tcp://127.0.0.1:{free_ports(1)[0]}"
    sub = Subscriber(endpoint, ("force",))
    peer = start_peer(endpoint, "force", "robot")
    try:
        def receive(count: int, timeout_s: float) -> list:
            got, deadline = [], time.monotonic() + timeout_s
            while len(got) < count:
                assert time.monotonic() < deadline, f"only {len(got)} of {count} messages"
                if (message := sub.recv(timeout_s=0.1)) is not None:
                    got.append(message)
            return got

        before = receive(20, 15.0)
        kill(peer)
        while sub.recv(timeout_s=0.3) is not None:  # whatever was in flight
            pass
        peer = start_peer(endpoint, "force", "robot")
        with caplog.at_level(logging.WARNING, logger="teleop.bus.pubsub"):
            after = receive(20, 15.0)
    finally:
        kill(peer)
        sub.close()
    assert [m.seq for m in before] == list(range(20))
    assert after[-1].seq == after[0].seq + 19 and after[0].seq < before[-1].seq + 5
    assert sub.stats.restarts == 2 and "restarted topic 'force'" in caplog.text  # force and heartbeat
    assert sub.heartbeat.is_alive("robot")


# --------------------------------------------------------------------------- slow subscriber

_SLOW = textwrap.dedent("""
    import json, sys, time
    from teleop.bus.pubsub import Subscriber
    from teleop.soak import rss_bytes
    endpoint, conflate, hwm = sys.argv[1], sys.argv[2] == "1", int(sys.argv[3])
    with Subscriber(endpoint, ("frame", "estimate"), conflate=conflate, high_water_mark=hwm) as sub:
        print("ready", flush=True)
        seqs, rss = [], []
        quiet_since = time.monotonic()
        while time.monotonic() - quiet_since < 1.5:
            message = sub.recv(timeout_s=0.1)
            if message is None:
                continue
            quiet_since = time.monotonic()
            seqs.append(message.seq)
            rss.append(rss_bytes())
            time.sleep(0.02)  # a consumer far slower than the 1 kHz publisher
        print(json.dumps({"seqs": seqs, "rss_max": max(rss), "rss_first": rss[0],
                          "gaps": sub.stats.gaps, "missed": sub.stats.missed}), flush=True)
""")


def slow_subscriber(endpoint: str, *, conflate: bool, hwm: int) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, "-c", _SLOW, endpoint, "1" if conflate else "0", str(hwm)],
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "ready"
    return process


def slow_result(process: subprocess.Popen) -> dict:
    import json

    out, _ = process.communicate(timeout=60)
    return json.loads(out.strip().splitlines()[-1])


FRAME = np.full(200_000, 0xFF, np.uint8)  # a large frame (200 kB), so an unbounded queue would show in RSS
FRAME[:2] = (0xFF, 0xD8)


@pytest.mark.slow
def test_slow_lossless_subscriber_blocks_the_publisher_and_loses_nothing():
    """Grasp data: memory bounded by the high water marks, the publisher blocks then times out."""
    hwm = 20
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", high_water_mark=hwm,
                   send_timeout_s=0.2) as pub:
        slow = slow_subscriber(pub.endpoint, conflate=False, hwm=hwm)
        pub.wait_for_subscriber("frame/left", timeout_s=5.0)
        sent = timeouts = 0
        for _ in range(300):
            try:
                pub.send("frame", t_capture_s=time.monotonic(), finger="left", index=sent, encoding="jpeg", data=FRAME)
                sent += 1
            except BusTimeoutError:  # the loss is reported to the sender, never silent
                timeouts += 1
                if timeouts >= 3:
                    break
        result = slow_result(slow)
    assert timeouts >= 3  # a 1 kHz sender cannot outrun a 50 Hz consumer 300 times without blocking
    assert result["seqs"] == list(range(sent))  # every message that was sent arrived, in order
    assert result["gaps"] == 0
    # Bounded: both high water marks plus kernel buffers, not the ~60 MB of all 300 frames.
    growth_mb = (result["rss_max"] - result["rss_first"]) / 2**20
    assert growth_mb < 2 * hwm * FRAME.nbytes / 2**20 + 10, growth_mb


@pytest.mark.slow
def test_slow_conflating_subscriber_keeps_the_newest_and_bounded_memory():
    """Display data: the publisher never blocks, the slow subscriber sees the newest."""
    with Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator") as pub:
        slow = slow_subscriber(pub.endpoint, conflate=True, hwm=50)
        pub.wait_for_subscriber("estimate", timeout_s=5.0)
        started = time.monotonic()
        for i in range(3000):
            pub.send("estimate", t_capture_s=float(i), grasp_id="g", method="series", E_pa=1e5, interval_pa=[5e4, 2e5],
                     state="ok", reason="x" * 1000, provisional=True, latency_s=0.0)
            if i % 100 == 0:
                time.sleep(0.01)
        # Never blocked on the slow peer: held to its pace (20 ms a message) the 3000 sends would take 60 s;
        # free, about 1 s (a margin for a stalled host).
        assert time.monotonic() - started < 20.0
        result = slow_result(slow)
    seqs = result["seqs"]
    assert seqs[-1] == 2999 and len(seqs) < 3000 and seqs == sorted(seqs)  # conflated, newest last
    assert result["missed"] <= 3000 - len(seqs)  # what the queues dropped is counted as gaps
    assert (result["rss_max"] - result["rss_first"]) / 2**20 < 10


def test_rss_is_read_for_this_process():
    assert 10 * 2**20 < rss_bytes() < 10 * 2**30


def test_robot_node_ignores_the_estimators_reload_model_command(caplog):
    from teleop.node import RobotNode
    from teleop.scene import load_scene

    scene = load_scene("quick")
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as robot,
        Publisher("tcp://127.0.0.1:*", lossless=True, source="operator") as operator,
        Subscriber(operator.endpoint, ("command",)) as commands,
        RobotNode(scene.settings, publisher=robot, commands=commands, scene=scene) as node,
        caplog.at_level(logging.DEBUG, logger="teleop.node"),
    ):
        operator.wait_for_subscriber("command", timeout_s=5.0)
        operator.send("command", t_capture_s=0.0, action="reload_model", params={})
        deadline = time.monotonic() + 5.0
        while "not for the robot node" not in caplog.text:
            assert time.monotonic() < deadline, "the command did not arrive"
            node.step()
        assert node.stats.bad_commands == 0 and not node.busy
