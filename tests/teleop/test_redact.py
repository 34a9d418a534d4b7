"""Passwords in URLs hidden for printing and storing; everything else left as it is."""

from __future__ import annotations

import pytest

from teleop.redact import redact_url, redacted


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("http://admin:Hunter2Pass@127.0.0.1:9/?action=stream", "http://admin:***@127.0.0.1:9/?action=stream"),
        ("rtsp://cam:pw@pi", "rtsp://cam:***@pi"),
        ("tcp://u:p@[::1]:5601", "tcp://u:***@[::1]:5601"),
        ("http://admin:p@ss@pi:8080/", "http://admin:***@pi:8080/"),  # an "@" in it: the last one ends it
        ("http://:secret@pi/", "http://:***@pi/"),
        # in a message, with the URL quoted
        ("<OpenCVCamera finger='left' source='http://a:secret@pi/x'>: cannot open",
         "<OpenCVCamera finger='left' source='http://a:***@pi/x'>: cannot open"),
    ],
)
def test_a_urls_password_is_replaced(text, expected):
    assert redact_url(text) == expected


@pytest.mark.parametrize(
    "text",
    ["0", "/dev/video0", "", "http://pi:8080/?action=stream", "http://user@pi:8080/?action=stream",
     "http://pi:8080/a:b@c", "tcp://127.0.0.1:5601", "see admin:secret@pi"],  # the last: no URL
)
def test_what_holds_no_password_is_unchanged(text):
    assert redact_url(text) == text


def test_every_string_in_plain_data_is_redacted_and_the_rest_kept():
    data = {"sensors": {"left": {"camera_source": "http://a:pw@pi/", "camera_hz": 30.0, "markers": False}},
            "list": ["http://b:pw@h", 1, None], "pair": ("0", "http://c:pw@h")}
    assert redacted(data) == {"sensors": {"left": {"camera_source": "http://a:***@pi/", "camera_hz": 30.0,
                                                   "markers": False}},
                              "list": ["http://b:***@h", 1, None], "pair": ("0", "http://c:***@h")}


def test_a_password_in_a_mapping_key_is_hidden_too():
    # e.g. a per-source table keyed by the camera URL, stored in a report
    data = {"http://admin:secret@pi:8080/?action=stream": {"frames": 3}, "plain": "x"}
    assert redacted(data) == {"http://admin:***@pi:8080/?action=stream": {"frames": 3}, "plain": "x"}


def test_a_load_cell_address_with_a_password_is_hidden_where_it_is_said():
    from teleop.devices.hx711 import TcpHx711
    from teleop.rig.load_cell_calibration import load_cell_source
    from teleop.settings import LoadCellSettings

    cell = LoadCellSettings(backend="tcp", address="tcp://u:secret@127.0.0.1:5601")
    said = f"{TcpHx711(cell)!r} {load_cell_source(cell)}"
    assert "secret" not in said and "u:***@127.0.0.1:5601" in said
