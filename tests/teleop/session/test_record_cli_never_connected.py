"""`teleop record` names each endpoint no handshake succeeded with, keeps what the others sent, and exits
with status 1 (teleop.session.record_cli, teleop.bus.handshakes)."""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import threading
import time
from pathlib import Path

import pytest
from support.bus import HEARD_WITHIN_S, force

import teleop.cli
from teleop.bus import Publisher
from teleop.bus.security import BusSecurity, init_keys
from teleop.session import record_cli
from teleop.session.recorder import RECORDING_STOPPED, RECORDING_STOPPED_STATUS, RecorderStats

LOOPBACK = "tcp://127.0.0.1:*"


class _UntilRefused(logging.Handler):
    """Set once the handshake watch warns (it notes the failed endpoint before it says so)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.warned = threading.Event()

    def emit(self, record: logging.LogRecord) -> None:
        self.warned.set()


@pytest.fixture
def refused(monkeypatch):
    """Records with a `stop` that publishes on ``feeding`` (if any) each time it is asked, and stops once a
    handshake failed and ``at_least`` messages were recorded (or after HEARD_WITHIN_S: the test then fails)."""
    handler = _UntilRefused()
    logger = logging.getLogger("teleop.bus.handshakes")
    logger.addHandler(handler)
    options: dict = {"feeding": None, "at_least": 0}

    def record_until(recorder, duration_s):
        deadline, sent = time.monotonic() + HEARD_WITHIN_S, iter(range(10**9))

        class Stop:
            def is_set(self) -> bool:
                if options["feeding"] is not None:
                    force(options["feeding"], next(sent))
                enough = handler.warned.is_set() and recorder.stats.messages >= options["at_least"]
                return enough or time.monotonic() > deadline

        return recorder.run(stop=Stop())

    monkeypatch.setattr(record_cli, "_record_until_stopped", record_until)
    yield options
    logger.removeHandler(handler)


def _settings(tmp_path: Path, keys_dir: Path | None) -> Path:
    path = tmp_path / "settings.toml"
    path.write_text("" if keys_dir is None else f'[bus]\nkeys_dir = "{keys_dir}"\n', encoding="utf-8")
    return path


def _record(tmp_path: Path, settings: Path, *endpoints: str, capsys) -> tuple[int, dict, str]:
    argv = ["record", "--out", str(tmp_path / "session.mcap"), "--settings", str(settings), "--json"]
    code = teleop.cli.main([*argv, *(a for e in endpoints for a in ("--endpoint", e))])
    out, err = capsys.readouterr()
    return code, json.loads(out.strip().splitlines()[-1]), err


def test_an_endpoint_that_refuses_the_recorders_key_is_named_and_the_others_are_kept(tmp_path, refused, capsys):
    init_keys(tmp_path / "keys")
    init_keys(tmp_path / "other")
    # the same server pair, but admitting another client only: the recorder's key is refused there
    shutil.copytree(tmp_path / "keys", tmp_path / "refusing")
    (tmp_path / "refusing" / "authorized" / "client.key").unlink()
    shutil.copyfile(tmp_path / "other" / "client.key", tmp_path / "refusing" / "authorized" / "other.key")
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=BusSecurity.load(tmp_path / "keys")) as admits,
        Publisher(LOOPBACK, lossless=False, source="robot",
                  security=BusSecurity.load(tmp_path / "refusing")) as refuses,
    ):
        refused.update(feeding=admits, at_least=3)
        code, summary, err = _record(tmp_path, _settings(tmp_path, tmp_path / "keys"), admits.endpoint,
                                     refuses.endpoint, capsys=capsys)
    assert code == record_cli.NEVER_CONNECTED_STATUS == 1
    assert list(summary["never_connected"]) == [refuses.endpoint]
    assert summary["messages"] >= 3 and summary["topics"]["force"] == summary["messages"]  # kept
    assert (f"nothing recorded from {refuses.endpoint}, no handshake with it succeeded: CURVE handshake with "
            f"{refuses.endpoint} refused (the server does not authorise this client's key)") in err
    assert f"nothing recorded from {admits.endpoint}" not in err
    assert "reconnecting every" not in err.split("nothing recorded from", 1)[1]  # the summary is after the fact


def test_a_recorder_without_keys_against_a_curve_publisher_exits_1_naming_it(tmp_path, refused, capsys):
    init_keys(tmp_path / "keys")
    with Publisher(LOOPBACK, lossless=False, source="robot", security=BusSecurity.load(tmp_path / "keys")) as pub:
        code, summary, err = _record(tmp_path, _settings(tmp_path, None), pub.endpoint, capsys=capsys)
    assert code == 1
    assert summary["messages"] == 0 and list(summary["never_connected"]) == [pub.endpoint]
    assert f"nothing recorded from {pub.endpoint}, no handshake with it succeeded:" in err
    assert "this process runs none" in err.split("nothing recorded from", 1)[1]


def test_a_write_error_keeps_its_status_and_last_line_beside_an_endpoint_never_connected(tmp_path, monkeypatch,
                                                                                       capsys):
    stats = RecorderStats(error="writing session.mcap failed: No space left on device",
                          never_connected={"tcp://127.0.0.1:1": "CURVE handshake with tcp://127.0.0.1:1 refused"})
    monkeypatch.setattr(record_cli, "_record_until_stopped", lambda *_: stats)
    parser = argparse.ArgumentParser()
    record_cli.add_arguments(parser)
    args = parser.parse_args(["--out", str(tmp_path / "session.mcap"), "--endpoint", "tcp://127.0.0.1:1"])
    assert record_cli.run(args) == RECORDING_STOPPED_STATUS  # `teleop demo` reads it: the session goes on
    err = capsys.readouterr().err.strip().splitlines()
    assert any(line.startswith("nothing recorded from tcp://127.0.0.1:1") for line in err)
    assert err[-1].startswith(RECORDING_STOPPED)
