"""Connecting the franky gripper to a host that accepts the connection but never answers: a time
limit, and Ctrl-C at once (libfranka's own handshake holds for 60 s, in C, deaf to signals)."""

from __future__ import annotations

import signal
import threading
import time

import pytest

import teleop.devices.franky_gripper as franky_gripper
from teleop.devices.gripper import make_gripper
from teleop.errors import DeviceTimeoutError
from teleop.settings import GripperSettings, Settings

# How long the fake handshake holds before failing as libfranka's would (60 s there). Far longer than
# any bound below, so that a loaded machine (a doctor run takes seconds there) cannot reach it.
HANG_S = 30.0


class _Interrupted(Exception):
    """What the test's SIGINT handler raises (a KeyboardInterrupt would end the pytest run)."""


@pytest.fixture
def silent_host(monkeypatch):
    """franky.Gripper whose handshake blocks as in C: for HANG_S, with SIGINT held off in its thread."""
    released = threading.Event()

    class SilentGripper:
        def __init__(self, host):
            old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                released.wait(HANG_S)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)
            raise RuntimeError(f"libfranka: Connection timeout to {host}")

    monkeypatch.setattr(franky_gripper.franky, "Gripper", SilentGripper)
    yield
    released.set()


def test_a_host_that_never_answers_times_out_naming_the_settings(silent_host):
    gripper = make_gripper(GripperSettings(backend="franky", host="10.255.255.1", connect_timeout_s=0.3))
    started = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match=r"^franky gripper at 10\.255\.255\.1: no answer within 0\.3 s "
                                                 r"\(`gripper\.connect_timeout_s`\): check the robot is on with FCI "
                                                 r"enabled and `gripper\.host`$"):
        gripper.connect()
    assert time.monotonic() - started < 1.5
    assert not gripper.connected


def test_ctrl_c_while_connecting_interrupts_at_once(silent_host):
    def interrupted(signum, frame):
        raise _Interrupted

    previous = signal.signal(signal.SIGINT, interrupted)
    main = threading.main_thread().ident
    timer = threading.Timer(0.3, signal.pthread_kill, (main, signal.SIGINT))
    gripper = make_gripper(GripperSettings(backend="franky", host="10.255.255.1", connect_timeout_s=30.0))
    started = time.monotonic()
    try:
        timer.start()
        with pytest.raises(_Interrupted):
            gripper.connect()
        assert time.monotonic() - started < 0.3 + 1.0
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert not gripper.connected


def test_doctor_says_what_to_do_once(silent_host):
    from teleop.system.doctor import check_devices

    settings = Settings(gripper=GripperSettings(backend="franky", host="10.255.255.1", connect_timeout_s=0.3))
    started = time.monotonic()
    gripper = next(c for c in check_devices(settings, duration_s=0.3) if c.name == "gripper")
    # The connect's own limit (0.3 s), not the handshake's (HANG_S): the whole doctor run, a simulated
    # grasp included, takes seconds on a loaded machine, but ends long before the handshake would.
    assert time.monotonic() - started < HANG_S / 2
    assert not gripper.ok and gripper.problem.startswith("cannot open: franky gripper at 10.255.255.1: no answer")
    assert gripper.problem.count("FCI enabled") == 1, gripper.problem
