"""Fixtures for the device contract suites: records to replay, loopback servers, simulators."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator

import cv2
import numpy as np
import pytest

from teleop.record import FrameStream, GraspRecord, Provenance, Samples
from teleop.settings import SensorSettings


def _make_record(
    *,
    duration_s: float = 0.5,
    force_hz: float = 80.0,
    width_hz: float = 10.0,
    camera_hz: float = 30.0,
    frame_shape: tuple[int, int, int] = (48, 64, 3),
    command_grasp_s: float | None = None,
    seed: int = 0,
) -> GraspRecord:
    """A short synthetic grasp: squeeze force ramp, closing widths, noisy frames per finger."""
    rng = np.random.default_rng(seed)
    t_force = 2.0 + np.arange(0.0, duration_s, 1.0 / force_hz)
    t_width = 2.0 + np.arange(0.0, duration_s, 1.0 / width_hz) + 0.013
    fingers = ("left", "right")
    streams = []
    for k, finger in enumerate(fingers):
        t_frames = 2.0 + np.arange(0.0, duration_s, 1.0 / camera_hz) + 0.004 * (k + 1)
        frames = rng.integers(0, 255, (len(t_frames), *frame_shape), dtype=np.uint8)
        streams.append(FrameStream.from_frames(finger, t_frames, frames, encoding="jpeg", jpeg_quality=80))
    force = np.clip((t_force - 2.1) * 40.0, 0.0, None) + rng.normal(0.0, 0.02, t_force.size)
    width = 0.05 - 0.02 * np.clip((t_width - 2.0) / duration_s, 0.0, 1.0) ** 0.5
    events = {} if command_grasp_s is None else {"command_grasp": command_grasp_s}
    return GraspRecord(
        sensors=tuple(SensorSettings(finger=f) for f in fingers),
        frames=tuple(streams),
        force_n=Samples(t_force, force),
        width_m=Samples(t_width, width),
        provenance=Provenance(source="simulated", seed=seed, model="synthetic-test"),
        events=events,
    )


@pytest.fixture
def make_record() -> Callable[..., GraspRecord]:
    return _make_record


@pytest.fixture(scope="module")
def franky_sim_host(franky_sim_robot) -> str:
    """The address the franky-sim robot serves the libfranka protocol on (loopback)."""
    return franky_sim_robot.hostname


def _jpegs(n: int, shape=(480, 640, 3), seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        image = rng.integers(0, 255, shape, dtype=np.uint8)
        cv2.putText(image, str(i), (50, 200), cv2.FONT_HERSHEY_SIMPLEX, 4, (255, 255, 255), 8)
        out.append(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes())
    return out


@pytest.fixture
def jpeg_frames() -> Callable[..., list[bytes]]:
    return _jpegs


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    """(master fd, slave device path) of a pseudo-terminal: a serial line without hardware."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline: bytes pass as a serial port's would
    yield master, os.ttyname(slave)
    with contextlib.suppress(OSError):  # a test may have closed the master: the line hung up
        os.close(master)
    os.close(slave)


def _hardware_env(name: str) -> str:
    value = os.environ.get(name, "")
    if not value:
        pytest.skip(f"no hardware: set {name} to run this backend on a real device")
    return value


@pytest.fixture
def hardware_env() -> Callable[[str], str]:
    """Reads a hardware flag (e.g. COMPLIANCE_TELEOP_FRANKY_HOST), skipping the test when unset."""
    return _hardware_env
