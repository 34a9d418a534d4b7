"""``teleop doctor`` names a source with a password without the password."""

from __future__ import annotations

import json
import socket

import pytest
from support.rig_settings import rig_settings

from teleop.cli import main


def _closed_port() -> int:
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    return port


@pytest.mark.slow
@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_a_camera_urls_password_is_hidden_in_the_report(tmp_path, capsys, json_flag):
    port = _closed_port()
    path = rig_settings(tmp_path, {
        "sensors.left.camera_backend": "opencv",
        "sensors.left.camera_source": f"http://admin:Hunter2Pass@127.0.0.1:{port}/?action=stream",
        "load_cell.backend": "tcp", "load_cell.address": f"tcp://cell:CellPass@127.0.0.1:{_closed_port()}",
    })
    code = main(["doctor", "--duration-s", "1", "--settings", str(path), *json_flag])
    out = capsys.readouterr().out
    assert code == 1
    assert "Hunter2Pass" not in out and "CellPass" not in out
    devices = json.loads(out)["devices"] if json_flag else None
    camera = (next(d["problem"] for d in devices if d["name"] == "camera left") if devices
              else next(line for line in out.splitlines() if line.startswith("camera left")))
    assert f"http://admin:***@127.0.0.1:{port}/?action=stream" in camera
