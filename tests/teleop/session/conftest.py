"""A synthetic session published on loopback and recorded once, shared by the session tests."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from teleop.bus import Message, Publisher
from teleop.catalogue import default_catalogue_path
from teleop.session import SessionRecorder
from teleop.settings import Settings, load_settings

OBJECT = "stress_ball"  # in configs/objects.toml


def jpeg(rng: np.random.Generator, ext: str = ".jpg") -> bytes:
    image = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def publish_session(pub: Publisher, *, pause_s: float = 0.0, seed: int = 0) -> list[Message]:
    """Publish a small session; returns every message as sent (heartbeats included).

    Grasp g0 names its object, g1 does not, g2 never ends. Left frames are JPEG and carry
    the grasp id; right frames are PNG and carry none (they belong to the open grasp).
    One force message and one estimate lie outside any grasp; each end is announced twice.
    """
    rng = np.random.default_rng(seed)
    sent = [pub.send("heartbeat", t_capture_s=99.0, interval_s=pub.heartbeat_s)]
    t = 100.0
    sent.append(pub.send("force", t_capture_s=t, t_s=[t - 0.1, t], value_n=[0.0, 0.01]))
    for g, (name, ends) in enumerate(((OBJECT, True), (None, True), (None, False))):
        gid = f"g{g}"
        sent.append(
            pub.send(
                "command",
                t_capture_s=t,
                action="start_grasp",
                grasp_id=gid,
                params={"target_force_n": 10.0},
            )
        )
        sent.append(
            pub.send("grasp_event", t_capture_s=t, event="start", grasp_id=gid, object_name=name)
        )
        for k in range(4):
            t += 1 / 30
            sent.append(
                pub.send(
                    "frame",
                    t_capture_s=t,
                    finger="left",
                    grasp_id=gid,
                    index=k,
                    encoding="jpeg",
                    data=jpeg(rng),
                )
            )
            sent.append(
                pub.send(
                    "frame",
                    t_capture_s=t + 0.002,
                    finger="right",
                    index=k,
                    encoding="png",
                    data=jpeg(rng, ".png"),
                )
            )
            force_t = t - np.linspace(1 / 30, 0, 3, endpoint=False)[::-1]
            value = rng.uniform(0, 10, 3).astype(np.float32 if g == 1 else np.float64)
            sent.append(pub.send("force", t_capture_s=t, grasp_id=gid, t_s=force_t, value_n=value))
            sent.append(
                pub.send(
                    "width", t_capture_s=t, grasp_id=gid, t_s=[t - 0.1], value_m=[0.05 - 0.001 * k]
                )
            )
            sent.append(
                pub.send(
                    "estimate",
                    t_capture_s=t,
                    grasp_id=gid,
                    method="hertz",
                    E_pa=1e5 * (k + 1),
                    interval_pa=[5e4, None],
                    state="ok",
                    reason="",
                    provisional=True,
                    latency_s=0.01,
                )
            )
            if pause_s:
                time.sleep(pause_s)
        if ends:
            t += 0.1
            sent.append(
                pub.send("grasp_event", t_capture_s=t, event="end", grasp_id=gid, object_name=name)
            )
            # the estimator announces the end again once it has its final estimate
            sent.append(pub.send("grasp_event", t_capture_s=t, event="end", grasp_id=gid))
    sent.append(
        pub.send(
            "estimate",
            t_capture_s=t,
            grasp_id="g2",
            method="series",
            E_pa=None,
            interval_pa=[None, None],
            state="insufficient_data",
            reason="grasp never ended",
            provisional=False,
            latency_s=0.0,
        )
    )
    return sent


def wait_for(
    condition: Callable[[], bool], timeout_s: float = 10.0, what: str = "condition"
) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


@contextmanager
def recording(out, endpoints, **options) -> Iterator[SessionRecorder]:
    """A recorder running in a thread until the block ends."""
    recorder = SessionRecorder(out, endpoints, **options)
    stop = threading.Event()
    thread = threading.Thread(target=recorder.run, kwargs={"stop": stop}, daemon=True)
    thread.start()
    try:
        yield recorder
    finally:
        stop.set()
        thread.join(10)
        assert not thread.is_alive(), "recorder thread did not stop"


def body_equal(a: Message, b: Message) -> bool:
    if a.body.keys() != b.body.keys():
        return False
    for key, value in a.body.items():
        other = b.body[key]
        if isinstance(value, np.ndarray):
            if not (
                isinstance(other, np.ndarray)
                and value.dtype == other.dtype
                and np.array_equal(value, other)
            ):
                return False
        elif value != other:
            return False
    return True


@pytest.fixture(scope="session")
def session_settings(tmp_path_factory) -> Settings:
    """Shipped settings, with a tiny calibration file on the left sensor and none on the right.

    The shipped calibrations are large; tests that cut logs or fill a small fake disk need the
    attachments small.
    """
    folder = tmp_path_factory.mktemp("calibration")
    calibration = folder / "left_cal.npz"
    np.savez(calibration, gain=np.arange(6.0))
    settings = load_settings()
    sensors = tuple(
        dataclasses.replace(s, calibration=str(calibration) if s.finger == "left" else "")
        for s in settings.sensors
    )
    return dataclasses.replace(settings, sensors=sensors)


@dataclasses.dataclass(frozen=True)
class Recorded:
    path: Path
    sent: list[Message]
    settings: Settings
    stats: object


@pytest.fixture(scope="session")
def recorded(tmp_path_factory, session_settings) -> Recorded:
    """The synthetic session, published on tcp loopback (spread over ~0.4 s) and recorded."""
    path = tmp_path_factory.mktemp("session") / "session.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        recording(
            path,
            [pub.endpoint],
            settings=session_settings,
            scene="quick",
            catalogue=default_catalogue_path(),
            chunk_bytes=8 * 1024,
        ) as recorder,
    ):
        pub.wait_for_subscriber("", timeout_s=5.0)
        sent = publish_session(pub, pause_s=0.03)
        wait_for(
            lambda: recorder.stats.messages == len(sent), what="the recorder to store every message"
        )
    assert recorder.stats.error is None
    return Recorded(path, sent, session_settings, recorder.stats)


@pytest.fixture(scope="session")
def helpers() -> SimpleNamespace:
    """The helpers above, for test modules (conftest cannot be imported under importlib mode)."""
    return SimpleNamespace(
        publish_session=publish_session,
        wait_for=wait_for,
        recording=recording,
        body_equal=body_equal,
        jpeg=jpeg,
        object_name=OBJECT,
    )
