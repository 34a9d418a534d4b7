"""The settings a log stores carry no password of a URL in them."""

from __future__ import annotations

import dataclasses
import json

from mcap.reader import make_reader

from teleop.session import LogReader, SessionRecorder
from teleop.session.logfile import SETTINGS_ATTACHMENT

URL = "http://admin:Hunter2Pass@127.0.0.1:9/?action=stream"


def test_the_settings_attachment_hides_a_camera_urls_password(tmp_path, session_settings):
    sensors = tuple(dataclasses.replace(s, camera_backend="opencv", camera_source=URL) if s.finger == "left" else s
                    for s in session_settings.sensors)
    settings = dataclasses.replace(session_settings, sensors=sensors)
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, "tcp://127.0.0.1:1", settings=settings):
        pass
    with path.open("rb") as f:
        stored = next(a.data for a in make_reader(f).iter_attachments() if a.name == SETTINGS_ATTACHMENT)
    assert b"Hunter2Pass" not in stored
    assert json.loads(stored)["sensors"]["left"]["camera_source"] == "http://admin:***@127.0.0.1:9/?action=stream"
    # still the settings the session ran with, as export reads them, but for the password
    assert LogReader(path).info().settings().sensor("left") == dataclasses.replace(
        settings.sensor("left"), camera_source="http://admin:***@127.0.0.1:9/?action=stream")
