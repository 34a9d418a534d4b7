"""The ``haptics`` commands: devices, protocol, encode, try."""

from __future__ import annotations

import json
import math

import pytest

from haptics.cli import commands, main
from haptics.mapping import stiffness_fraction
from haptics.protocol import REPORT_DESCRIPTOR, decode_output_report
from haptics.settings import display_settings
from teleop.settings import default_settings_path, load_settings
from teleop.units import format_pa


def last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.parametrize("name", sorted(commands()))
def test_help_runs(name, capsys):
    with pytest.raises(SystemExit) as exited:
        main([name, "--help"])
    assert exited.value.code == 0
    assert "--json" in capsys.readouterr().out


def test_protocol_prints_layouts_and_descriptor(capsys):
    assert main(["protocol"]) == 0
    out = capsys.readouterr().out
    assert REPORT_DESCRIPTOR.hex(" ") in out
    for field in ("`level`", "`uncertainty`", "`sequence`", "`watchdog_ms`", "`faults`"):
        assert field in out
    assert main(["protocol", "--json"]) == 0
    data = last_json(capsys)
    assert bytes.fromhex(data["descriptor_hex"]) == REPORT_DESCRIPTOR
    assert [r["size"] for r in data["reports"]] == [8, 17, 7, 9]
    assert [r["since_version"] for r in data["reports"]] == [1, 1, 1, 2]
    assert data["protocol_versions"] == [1, 2]
    assert data["descriptors_hex"]["2"] == REPORT_DESCRIPTOR.hex()
    assert len(bytes.fromhex(data["descriptors_hex"]["1"])) == 39


def test_protocol_shows_the_grip_report(capsys):
    assert main(["protocol"]) == 0
    out = capsys.readouterr().out
    assert "INPUT report 0x04: grip (9 bytes, version 2 and later)" in out
    for field in ("`buttons`", "`position`", "`force`", "no force sensor", "enable (dead-man"):
        assert field in out
    assert "Report ID (0x04)" in out and "Usage (0x05: grip)" in out


def test_encode_prints_the_report(capsys):
    assert main(["encode", "--level", "4660", "--uncertainty", "42", "--sequence", "7",
                 "--rigid", "--stale", "--protocol-version", "1"]) == 0
    assert capsys.readouterr().out.strip() == "01 11 05 34 12 2a 07 39"
    # PROTOCOL.md writes the level in hex: the same report
    assert main(["encode", "--level", "0x1234", "--uncertainty", "0x2a", "--sequence", "7",
                 "--rigid", "--stale", "--protocol-version", "1"]) == 0
    assert capsys.readouterr().out.strip() == "01 11 05 34 12 2a 07 39"
    assert main(["encode", "--level", "1", "--fading", "--sequence", "128", "--json",
                 "--protocol-version", "1"]) == 0
    assert last_json(capsys)["report_hex"] == "01110801000080ee"
    # By default the newest version, 2: only the version nibble and the CRC differ.
    assert main(["encode", "--level", "4660", "--uncertainty", "42", "--sequence", "7",
                 "--rigid", "--stale", "--json"]) == 0
    data = last_json(capsys)
    assert (data["report_hex"], data["protocol_version"]) == ("01210534122a079c", 2)


def test_encode_refuses_bad_fields_in_one_line(capsys):
    assert main(["encode", "--level", "70000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "haptics encode: error: --level 70000: expected an integer in [0, 65535]"
    assert main(["encode", "--level", "1", "--rigid", "--unknown"]) == 2
    assert "rigid and unknown" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--level", "-1"], "--level -1: expected an integer in [0, 65535]"),
        (["--level", "1", "--sequence", "256"], "--sequence 256: expected an integer in [0, 255]"),
        (["--level", "1", "--sequence", "-1"], "--sequence -1: expected an integer in [0, 255]"),
        (["--level", "1", "--uncertainty", "0x100"], "--uncertainty 256: expected an integer in [0, 255]"),
    ],
)
def test_encode_names_the_option_and_its_range(options, message, capsys):
    assert main(["encode", *options]) == 2
    assert capsys.readouterr().err.strip() == f"haptics encode: error: {message}"


def test_try_maps_and_writes_to_the_simulated_display(capsys):
    assert main(["try", "--backend", "sim", "--e-pa", "2e5", "--low-pa", "1e5", "--high-pa",
                 "4e5", "--json"]) == 0
    data = last_json(capsys)
    shipped = load_settings()
    # The shipped range: 5 kPa to the estimating sensor's resolution limit.
    assert (data["e_soft_pa"], data["e_rigid_pa"]) == (5e3, shipped.resolution_limit_pa)
    assert data["just_noticeable_steps"] == pytest.approx(math.log(shipped.resolution_limit_pa / 5e3) / math.log(1.15))
    expected = round(stiffness_fraction(2e5, e_soft_pa=5e3, e_rigid_pa=shipped.resolution_limit_pa)
                     * data["level_max"])
    assert data["level"] == expected
    report = decode_output_report(bytes.fromhex(data["report_hex"]))
    assert report.command.level == expected
    assert report.command.uncertainty == round(20 * 0.6020599913)  # log10(4e5 / 1e5)
    assert data["status"] == {"state": "rendering", "level": expected, "faults": [], "sequence": 0}


def test_try_says_the_modulus_and_the_range_to_three_figures(capsys):
    assert main(["try", "--backend", "sim", "--e-pa", "30316.129536967757"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    rigid_end = format_pa(load_settings().resolution_limit_pa)  # the shipped range's stiff end
    assert line.startswith("E 30.3 kPa (ok) -> ") and f"of the range 5 kPa..{rigid_end} (" in line


def test_try_without_a_modulus_names_the_option(capsys):
    assert main(["try", "--backend", "sim"]) == 2
    assert "--e-pa: expected Young's modulus in Pa" in capsys.readouterr().err


def test_try_insufficient_data_and_rigid(capsys):
    assert main(["try", "--state", "insufficient_data", "--json"]) == 0
    assert last_json(capsys)["command"]["unknown"] is True
    assert main(["try", "--state", "lower_bound", "--e-pa", "3e10", "--json"]) == 0
    data = last_json(capsys)
    assert data["command"]["rigid"] is True and data["level"] == data["level_max"]
    # An ok estimate whose interval spans the display's whole range is shown unknown, and says why.
    assert main(["try", "--e-pa", "1e5", "--low-pa", "100", "--high-pa", "1e9", "--json"]) == 0
    captured = capsys.readouterr()
    assert "spans the display's whole range" in captured.err
    assert json.loads(captured.out)["command"]["unknown"] is True


def test_try_renders_a_bound_at_the_resolution_limit_rigid_and_one_below_at_its_bound(capsys):
    limit = load_settings().resolution_limit_pa
    assert main(["try", "--state", "lower_bound", "--e-pa", repr(limit), "--json"]) == 0
    data = last_json(capsys)
    assert data["command"]["rigid"] is True and data["level"] == data["level_max"]
    assert data["uncertainty_decades"] == 0.0
    below = limit / 1.15  # one just-noticeable step softer
    assert main(["try", "--state", "lower_bound", "--e-pa", repr(below), "--json"]) == 0
    data = last_json(capsys)
    assert data["command"]["rigid"] is False and data["level"] < data["level_max"]
    assert data["display_fraction"] == pytest.approx(stiffness_fraction(below, e_soft_pa=5e3, e_rigid_pa=limit))


def test_try_takes_an_explicit_rigid_end_from_the_settings(tmp_path, capsys):
    text = default_settings_path().read_text()
    path = tmp_path / "settings.toml"
    path.write_text(text.replace("e_soft_pa = 5000.0", "e_soft_pa = 5000.0\ne_rigid_pa = 1.0e9"))
    assert main(["try", "--settings", str(path), "--e-pa", "1e8", "--json"]) == 0
    data = last_json(capsys)
    assert data["e_rigid_pa"] == 1e9 and data["command"]["rigid"] is False


@pytest.mark.parametrize("state", ["ok", "lower_bound", "insufficient_data"])
@pytest.mark.parametrize("e_pa", ["nan", "inf", "-1"])
def test_try_refuses_a_bad_modulus_in_every_state(state, e_pa, capsys):
    assert main(["try", "--state", state, "--e-pa", e_pa, "--json"]) == 2
    captured = capsys.readouterr()
    assert f"--e-pa {float(e_pa)}: expected Young's modulus in Pa, a finite number > 0" in captured.err
    assert captured.out == ""  # no JSON, let alone NaN in it


@pytest.mark.parametrize("timeout_s", ["-1", "nan", "inf"])
def test_try_refuses_a_bad_timeout_before_writing_to_the_display(fake_hid, timeout_s, capsys):
    usb = fake_hid.plug()
    assert main(["try", "--backend", "hid", "--e-pa", "1e7", "--timeout-s", timeout_s]) == 2
    assert f"--timeout-s {float(timeout_s)}: expected a finite number of seconds >= 0" in capsys.readouterr().err
    assert usb.writes == []


@pytest.mark.parametrize(
    ("options", "bad"),
    [
        (["serve", "--backend", "sim", "--tick-s", "inf", "--duration-s", "0.5"], "--tick-s: 'inf'"),
        (["serve", "--backend", "sim", "--tick-s", "0"], "--tick-s: '0'"),
        (["serve", "--backend", "sim", "--duration-s", "nan"], "--duration-s: 'nan'"),
        (["serve", "--backend", "sim", "--duration-s", "-1"], "--duration-s: '-1'"),
        (["operate", "--headless", "--input", "sim", "--duration-s", "nan"], "--duration-s: 'nan'"),
        (["operate", "--headless", "--input", "sim", "--duration-s", "-1"], "--duration-s: '-1'"),
        (["operate", "--headless", "--input", "sim", "--duration-s", "inf"], "--duration-s: 'inf'"),
    ],
)
def test_serve_and_operate_refuse_a_bad_time_as_a_usage_error(options, bad, capsys):
    with pytest.raises(SystemExit) as exited:
        main(options)
    assert exited.value.code == 2
    assert f"argument {bad}: expected a number > 0" in capsys.readouterr().err


@pytest.mark.parametrize("tick_s", ["5", "1e9"])
def test_serve_refuses_a_tick_longer_than_the_keepalive_and_heartbeat_it_keeps(tick_s, capsys):
    # A longer wait for a message would starve the display's keep-alive and the heartbeat (1e9 s
    # overflowed zmq_poll, a traceback): refused before anything opens, naming the option and the settings.
    settings = load_settings()
    assert main(["serve", "--backend", "sim", "--duration-s", "0.1", "--tick-s", tick_s]) == 2
    err = capsys.readouterr().err
    assert f"--tick-s {float(tick_s):g}: longer than a period the renderer must keep" in err
    assert f"[display] keepalive_s = {display_settings(settings).keepalive_s:g} s" in err
    assert f"[bus] heartbeat_s = {settings.bus.heartbeat_s:g} s" in err
    assert "Traceback" not in err


def test_try_over_hid(fake_hid, capsys):
    usb = fake_hid.plug()
    assert main(["try", "--backend", "hid", "--e-pa", "1e7", "--json"]) == 0
    data = last_json(capsys)
    assert usb.writes == [bytes.fromhex(data["report_hex"])]
    assert "/dev/hidraw0" in data["display"]


def test_try_over_hid_with_nothing_plugged_in(fake_hid, capsys):
    assert main(["try", "--backend", "hid", "--e-pa", "1e7"]) == 2
    assert "no HID display 1209:5EF7 is plugged in" in capsys.readouterr().err


def test_devices_says_when_none_are_plugged_in(fake_hid, capsys):
    assert main(["devices", "--json"]) == 0
    captured = capsys.readouterr()
    assert "no softness display 1209:5EF7 is plugged in" in captured.err
    assert json.loads(captured.out)["count"] == 0


def test_devices_lists_what_is_plugged_in(fake_hid, capsys):
    fake_hid.plug(serial="SD-42")
    fake_hid.plug(vendor_id=0x046D)  # someone else's device
    assert main(["devices", "--json"]) == 0
    data = last_json(capsys)
    assert data["count"] == 1
    assert data["devices"][0]["path"] == "/dev/hidraw0"
    assert data["devices"][0]["serial_number"] == "SD-42"
    assert main(["devices", "--vendor-id", "0x046d", "--json"]) == 0
    assert last_json(capsys)["count"] == 1


def test_devices_refuses_a_bad_usb_id(capsys):
    with pytest.raises(SystemExit):
        main(["devices", "--vendor-id", "0x12345"])
    assert "outside 0x0000-0xFFFF" in capsys.readouterr().err
