"""HX711 line protocols, robust parsing on both links, the bridge and its command."""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from teleop.cli import main
from teleop.devices.hx711 import CLOCK_RESYNC_FRAMES, BridgeClock, parse_tcp_address
from teleop.devices.hx711_bridge import FakeHx711, Hx711Bridge, SerialCounts
from teleop.devices.hx711_protocol import (
    COUNTS_MAX,
    COUNTS_MIN,
    MAX_LINE_BYTES,
    LineSplitter,
    Unreadable,
    format_frame,
    parse_frame,
    parse_serial_line,
)
from teleop.devices.loadcell import make_load_cell
from teleop.errors import BackendNotFoundError, DeviceError
from teleop.settings import LoadCellSettings

CAL = {"counts_per_n": 1000.0, "tare_counts": 0, "timeout_s": 1.0}


# --------------------------------------------------------------------------- pure protocol


@pytest.mark.parametrize("line, counts", [(b"123", 123), (b"  -4567\r", -4567), (b"+8", 8), (b"0", 0)])
def test_serial_lines_that_are_readings(line, counts):
    assert parse_serial_line(line) == counts


@pytest.mark.parametrize(
    "line, reason",
    [
        (b"", "garbage"),
        (b"12a", "garbage"),
        (b"1.5", "garbage"),
        (b"weight: 12", "garbage"),
        (b"\xff\xfe", "garbage"),
        ("١٢".encode(), "garbage"),  # digits, but not ASCII ones
        (b"%d" % (2**23), "out_of_range"),
        (b"%d" % COUNTS_MAX, "out_of_range"),  # the upper rail: a saturated HX711
        (b"%d" % COUNTS_MIN, "out_of_range"),
        (b"999999999", "out_of_range"),
    ],
)
def test_serial_lines_that_are_not(line, reason):
    with pytest.raises(Unreadable) as info:
        parse_serial_line(line)
    assert info.value.reason == reason


def test_line_splitter_joins_partial_lines_and_drops_overlong_ones():
    lines = LineSplitter(skip_first=True)
    assert lines.feed(b"89\n12") == []  # "89" is the tail of a line begun before we listened
    assert lines.feed(b"34\n56\n7") == [b"1234", b"56"]
    assert lines.feed(b"x" * (MAX_LINE_BYTES + 5)) == []  # a line that never ends is dropped early
    assert lines.feed(b"still the long line\n42\n") == [b"42"]
    assert lines.feed(b"y" * (MAX_LINE_BYTES + 1) + b"\n43\n") == [b"43"]
    assert lines.overlong == 2


@given(st.integers(0, 2**40), st.floats(-1e9, 1e9, allow_nan=False), st.integers(COUNTS_MIN + 1, COUNTS_MAX - 1))
def test_frames_round_trip(seq, t, counts):
    frame = format_frame(seq, t, counts)
    assert frame.endswith(b"\n") and frame.count(b"\n") == 1 and len(frame) <= MAX_LINE_BYTES
    assert parse_frame(frame[:-1]) == (seq, t, counts)


@pytest.mark.parametrize(
    "line, reason",
    [
        (b"12345", "garbage"),  # the published rig's bare numbers
        (b"{not json", "garbage"),
        (b'{"v":1,"seq":0,"t_bridge_s":1.0}', "garbage"),
        (b'{"v":1,"seq":0,"t_bridge_s":1.0,"counts":5,"x":1}', "garbage"),
        (b'{"v":2,"seq":0,"t_bridge_s":1.0,"counts":5}', "version"),
        (b'{"v":true,"seq":0,"t_bridge_s":1.0,"counts":5}', "version"),
        (b'{"v":1,"seq":-1,"t_bridge_s":1.0,"counts":5}', "garbage"),
        (b'{"v":1,"seq":1.0,"t_bridge_s":1.0,"counts":5}', "garbage"),
        (b'{"v":1,"seq":0,"t_bridge_s":NaN,"counts":5}', "garbage"),
        (b'{"v":1,"seq":0,"t_bridge_s":"1","counts":5}', "garbage"),
        (b'{"v":1,"seq":0,"t_bridge_s":1.0,"counts":8388607}', "out_of_range"),
        (b"[1,2,3]", "garbage"),
    ],
)
def test_frames_that_are_refused(line, reason):
    with pytest.raises(Unreadable) as info:
        parse_frame(line)
    assert info.value.reason == reason


def test_bridge_clock_follows_the_least_delayed_frame():
    clock = BridgeClock()
    # bridge samples every 12.5 ms; network delays 5, 2, 9, 2 ms
    arrivals = [(0.0, 100.005), (0.0125, 100.0145), (0.025, 100.034), (0.0375, 100.0395)]
    host = [clock.to_host(tb, arrived) for tb, arrived in arrivals]
    assert host[0] == pytest.approx(100.005)
    assert np.diff(host[1:]) == pytest.approx([0.0125, 0.0125])  # jitter no longer moves them
    assert clock.offset_s == pytest.approx(100.002)


def test_bridge_clock_refuses_a_time_going_back_or_moving_it_by_seconds():
    clock = BridgeClock()
    assert clock.to_host(10.0, 100.005) == pytest.approx(100.005)
    with pytest.raises(Unreadable, match="goes back") as back:
        clock.to_host(9.0, 100.02)
    with pytest.raises(Unreadable, match="move the clock") as jump:
        clock.to_host(1e15, 100.03)  # a bogus far-future time
    assert back.value.reason == jump.value.reason == "implausible"
    assert clock.to_host(10.0375, 100.045) == pytest.approx(100.0425)  # the clock is as it was
    assert clock.offset_s == pytest.approx(90.005)


def test_bridge_clock_starts_over_when_frames_agree_with_one_another_not_with_it():
    clock = BridgeClock()
    assert clock.to_host(1e15, 100.0) == pytest.approx(100.0)  # the very first time is bogus
    for i in range(1, CLOCK_RESYNC_FRAMES):
        with pytest.raises(Unreadable):
            clock.to_host(5.0 + i * 0.0125, 100.002 + i * 0.0125)
    i = CLOCK_RESYNC_FRAMES
    assert clock.to_host(5.0 + i * 0.0125, 100.002 + i * 0.0125) == pytest.approx(100.002 + i * 0.0125)
    assert clock.to_host(5.1, 100.104) == pytest.approx(100.102)


@pytest.mark.parametrize("address", ["127.0.0.1:5601", "tcp://:5601", "tcp://host", "udp://h:1", "tcp://h:99999"])
def test_bad_tcp_addresses_are_named(address):
    with pytest.raises(DeviceError, match="tcp://host:port"):
        parse_tcp_address(address)


# --------------------------------------------------------------------------- links


def test_serial_link_skips_garbage_and_keeps_the_readings(pty_pair, caplog):
    master, port = pty_pair
    with make_load_cell(LoadCellSettings(backend="serial", port=port, **CAL)) as cell:
        os.write(master, b"7\n1000\nhello\n")
        os.write(master, b"20")  # a reading split across two writes
        time.sleep(0.05)
        os.write(master, b"00\r\n%d\n" % (2**23) + b"z" * 300 + b"\n-500\nworld\n")
        got = []
        while len(got) < 3:
            got.extend(cell.read(timeout_s=1.0).value)
        skipped = dict(cell.skipped)
    assert got == [1.0, 2.0, -0.5]
    assert skipped == {"garbage": 2, "out_of_range": 1, "overlong": 1}
    warnings = [r.message for r in caplog.records if r.levelno == logging.WARNING]
    assert sum("(garbage)" in w for w in warnings) == 1  # warned once, then counted quietly


def test_serial_port_errors_are_device_errors(tmp_path):
    with pytest.raises(DeviceError, match="port is empty"):
        make_load_cell(LoadCellSettings(backend="serial")).connect()
    with pytest.raises(DeviceError, match="cannot open"):
        make_load_cell(LoadCellSettings(backend="serial", port=str(tmp_path / "ttyNONE"))).connect()


def test_serial_links_without_pyserial_say_to_install_the_robot_extra(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "serial", None)  # `import serial` raises ImportError, as when not installed
    with pytest.raises(BackendNotFoundError, match=r"^load cell backend 'serial' cannot be loaded: .*serial.* "
                                                   r"\(install the 'robot' extra\)$"):
        make_load_cell(LoadCellSettings(backend="serial", port="/dev/ttyUSB9"))
    make_load_cell(LoadCellSettings(backend="tcp", address="tcp://127.0.0.1:9"))  # the tcp backend needs none
    with pytest.raises(BackendNotFoundError, match=r"--serial.*\(install the 'robot' extra\)"):
        SerialCounts("/dev/ttyUSB9")
    assert main(["hx711-bridge", "--serial", "/dev/ttyUSB9", "--duration-s", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teleop hx711-bridge: error: ") and "'robot' extra" in err and len(err.splitlines()) == 1


class _HandServer:
    """A TCP server sending exactly the bytes it is given, then closing."""

    def __init__(self, payload: bytes):
        self.server = socket.create_server(("127.0.0.1", 0))
        self.address = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.payload = payload
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        client, _ = self.server.accept()
        with client:
            client.sendall(self.payload)
            time.sleep(0.3)

    def close(self):
        self.server.close()


def test_tcp_link_counts_gaps_skips_garbage_and_reports_a_closed_bridge():
    payload = b"".join(
        [
            format_frame(0, 10.0, 1000),
            format_frame(1, 10.0125, 2000),
            b"3000\n",  # a bare number, as the published rig sent
            format_frame(5, 10.0625, 3000),  # readings 2..4 lost on the bridge
            format_frame(6, 10.075, 4000),
        ]
    )
    server = _HandServer(payload)
    try:
        with make_load_cell(LoadCellSettings(backend="tcp", address=server.address, **CAL)) as cell:
            samples = cell.read(timeout_s=1.0)
            while len(samples) < 4:
                more = cell.read(timeout_s=1.0)
                samples = type(samples)(np.r_[samples.t_s, more.t_s], np.r_[samples.value, more.value])
            with pytest.raises(DeviceError, match="closed the connection"):
                time.sleep(0.5)
                cell.read(timeout_s=0.5)
            assert (cell.gaps, cell.missed, dict(cell.skipped)) == (1, 3, {"garbage": 1})
    finally:
        server.close()
    assert samples.value.tolist() == [1.0, 2.0, 3.0, 4.0]
    # one burst: each frame is the least delayed so far, so each is stamped on arrival
    assert np.all(np.diff(samples.t_s) >= 0)


def test_a_repeated_or_reordered_reading_is_no_gap_and_the_next_one_is_not_lost(caplog):
    # Readings 0, 1, 2, then 1 again, then 3: nothing was lost on the bridge.
    payload = b"".join(format_frame(seq, 10.0 + 0.0125 * seq, 1000 * (seq + 1)) for seq in (0, 1, 2, 1, 3))
    server = _HandServer(payload)
    try:
        with (caplog.at_level(logging.WARNING, logger="teleop.devices.hx711"),
              make_load_cell(LoadCellSettings(backend="tcp", address=server.address, **CAL)) as cell):
            samples = _read_at_least(cell, 4)  # the repeated reading's time runs backwards: it is not kept
            assert (cell.gaps, cell.missed) == (0, 0)
    finally:
        server.close()
    assert samples.value.tolist()[-1] == 4.0  # reading 3
    assert "reading 1 came after reading 2 (repeated or out of order)" in caplog.text
    assert "lost" not in caplog.text


def _frames(t0: float, seqs, counts: int = 1000) -> bytes:
    return b"".join(format_frame(seq, t0 + seq * 0.0125, counts) for seq in seqs)


def _read_at_least(cell, n: int):
    samples = cell.read(timeout_s=1.0)
    while len(samples) < n:
        more = cell.read(timeout_s=1.0)
        samples = type(samples)(np.r_[samples.t_s, more.t_s], np.r_[samples.value, more.value])
    return samples


def test_tcp_link_skips_a_frame_with_a_bogus_time_and_keeps_host_clock_times(caplog):
    payload = b"".join([_frames(10.0, range(3)), format_frame(3, 1e15, 1000), _frames(10.0, range(4, 8)),
                        format_frame(8, 5.0, 1000), _frames(10.0, range(9, 12))])  # 8 goes back
    server = _HandServer(payload)
    before = time.monotonic()
    try:
        with caplog.at_level(logging.WARNING), make_load_cell(
            LoadCellSettings(backend="tcp", address=server.address, **CAL)
        ) as cell:
            samples = _read_at_least(cell, 10)
            after = time.monotonic()
            assert dict(cell.skipped) == {"implausible": 2}
    finally:
        server.close()
    assert len(samples) == 10
    assert before <= samples.t_s.min() and samples.t_s.max() <= after
    assert np.all(np.diff(samples.t_s) >= 0)
    assert sum("skipped a reading (implausible)" in r.getMessage() for r in caplog.records) == 1  # once per reason


def test_tcp_link_reconnects_to_a_restarted_bridge_with_a_new_clock():
    server = socket.create_server(("127.0.0.1", 0))
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"

    def serve():
        for t0 in (5000.0, 0.5):  # the bridge restarted: its clock starts near zero again
            client, _ = server.accept()
            with client:
                client.sendall(_frames(t0, range(5)))
                time.sleep(0.5)

    threading.Thread(target=serve, daemon=True).start()
    cell = make_load_cell(LoadCellSettings(backend="tcp", address=address, **CAL))
    try:
        stamps = []
        for _ in range(2):
            before = time.monotonic()
            with cell:
                samples = _read_at_least(cell, 5)
                assert not cell.skipped
            stamps.append((before, samples.t_s))
    finally:
        server.close()
    for before, t_s in stamps:
        assert len(t_s) == 5 and before <= t_s.min() and t_s.max() <= time.monotonic()


def test_tcp_connection_refused_is_a_device_error():
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(DeviceError, match="cannot connect"):
        make_load_cell(LoadCellSettings(backend="tcp", address=f"tcp://127.0.0.1:{port}")).connect()


# --------------------------------------------------------------------------- bridge side


def test_fake_cell_turns_force_into_counts_at_its_rate():
    fake = FakeHx711(counts_per_n=1000.0, tare_counts=50, rate_hz=100.0, force_n=lambda t: 2.0 + 100.0 * t)
    started = time.monotonic()
    counts = [fake() for _ in range(5)]
    # Four periods of 10 ms after the first. The upper bound, well below the 4 s of a rate taken as a
    # period (1 Hz), leaves a loaded machine room.
    assert 0.035 <= time.monotonic() - started < 2.0
    assert counts == [2050, 3050, 4050, 5050, 6050]
    noisy = [FakeHx711(counts_per_n=1.0, rate_hz=1000.0, noise_counts=10.0, seed=3)() for _ in range(2)]
    assert noisy[0] == noisy[1] != 0  # seeded
    assert FakeHx711(counts_per_n=1e9, rate_hz=1000.0, force_n=1.0)() == COUNTS_MAX - 1  # clipped below the rail


def test_bridge_serves_every_connected_host_the_same_readings():
    fake = FakeHx711(counts_per_n=1000.0, rate_hz=200.0, force_n=1.5)
    with Hx711Bridge(fake, host="127.0.0.1", port=0) as bridge:
        settings = LoadCellSettings(backend="tcp", address=bridge.address, **CAL)
        with make_load_cell(settings) as first, make_load_cell(settings) as second:
            a, b = first.read(timeout_s=1.0), second.read(timeout_s=1.0)
            assert bridge.clients == 2
    assert set(a.value) == set(b.value) == {1.5}


def test_serial_counts_source_reads_an_arduino_bridge(pty_pair):
    master, port = pty_pair
    source = SerialCounts(port)
    try:
        os.write(master, b"tail\n100\nnoise\n-200\n")
        assert [source(), source()] == [100, -200]
        started = time.monotonic()
        assert source() is None  # idle line: the bridge loop gets control back
        assert time.monotonic() - started >= 0.4
    finally:
        source.close()


@pytest.fixture
def unpluggable():
    """(master fd, device path, unplug) of a pseudo-terminal: unplug() closes the master, as pulling
    the device's cable ends its port."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    unplugged = threading.Event()

    def unplug() -> None:
        if not unplugged.is_set():
            unplugged.set()
            os.close(master)

    yield master, os.ttyname(slave), unplug
    unplug()
    os.close(slave)


def test_a_serial_source_that_goes_away_ends_the_bridge_and_closes_its_hosts(unpluggable):
    master, port, unplug = unpluggable
    told = []
    source = SerialCounts(port)
    try:
        with Hx711Bridge(source, host="127.0.0.1", port=0, on_failure=told.append) as bridge:
            with make_load_cell(LoadCellSettings(backend="tcp", address=bridge.address, **CAL)) as cell:
                deadline = time.monotonic() + 2.0
                while bridge.clients == 0 and time.monotonic() < deadline:  # a reading before would go to none
                    time.sleep(0.01)
                os.write(master, b"tail\n100\n")
                assert cell.read(timeout_s=1.0).value.tolist() == [0.1]
                unplug()
                # the host sees its link fail, not silence
                with pytest.raises(DeviceError, match="the bridge closed the connection"):
                    for _ in range(20):
                        cell.read(timeout_s=0.1)
            assert bridge.clients == 0
    finally:
        source.close()
    assert told == [bridge.failure] and bridge.failure.startswith(f"serial HX711 at {port}: the port failed: ")


def test_a_source_that_raises_ends_the_bridge_and_is_logged(caplog):
    def broken() -> int:
        raise ValueError("no counts")

    with Hx711Bridge(broken, host="127.0.0.1", port=0) as bridge:
        deadline = time.monotonic() + 2.0
        while bridge.failure is None and time.monotonic() < deadline:
            time.sleep(0.01)
    assert bridge.failure == "the source failed: ValueError('no counts')"
    assert any("stopped serving: the source failed" in r.message for r in caplog.records if r.levelno == logging.ERROR)


def test_bridge_command_exits_with_the_error_when_its_serial_device_goes_away(capsys, unpluggable):
    _, port, unplug = unpluggable
    said = []

    def unplug_once_serving() -> None:  # not before the bridge says it serves, however slowly it starts
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            said.append(capsys.readouterr())
            if any("serving on" in s.err for s in said):
                break
            time.sleep(0.01)
        unplug()

    threading.Thread(target=unplug_once_serving, daemon=True).start()
    # Within its 60 s: the error is the unplugged port's, not the duration's end.
    assert main(["hx711-bridge", "--serial", port, "--host", "127.0.0.1", "--port", "0", "--duration-s", "60"]) == 2
    serving, *errors = ("".join(s.err for s in said) + capsys.readouterr().err).splitlines()
    assert serving.startswith("hx711-bridge: serving on tcp://127.0.0.1:") and len(errors) == 1
    err = errors[0]
    assert err.startswith("teleop hx711-bridge: error: stopped serving tcp://127.0.0.1:")
    assert f"serial HX711 at {port}: the port failed: " in err


BRIDGE_COMMAND = [sys.executable, "-c", "import sys; from teleop.cli import main; sys.exit(main(sys.argv[1:]))",
                  "hx711-bridge"]


@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--port", "70000", "--port 70000: expected a TCP port in 0..65535"),
    ("--port", "-1", "--port -1: expected a TCP port in 0..65535"),
    ("--noise-counts", "-3", "--noise-counts -3.0: expected a number of counts >= 0"),
    ("--baud", "0", "--baud 0: LoadCellSettings.baud = 0: expected a value in [1200, 4000000]"),  # not the default
    ("--baud", "9600000", "--baud 9600000: LoadCellSettings.baud = 9600000: expected a value in [1200, 4000000]"),
])
def test_bridge_command_refuses_bad_options_in_one_line(capsys, option, value, expected):
    # --duration-s first: an option let through would serve briefly, not hang the test (the last one given counts)
    assert main(["hx711-bridge", "--fake", "--host", "127.0.0.1", "--port", "0", "--duration-s", "0.1", option, value]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"teleop hx711-bridge: error: {expected}") and captured.err.count("\n") == 1
    assert "serving" not in captured.err  # refused before the server was opened


@pytest.mark.parametrize("value", ["-1", "inf", "0"])
def test_bridge_command_refuses_a_duration_that_is_not_positive(capsys, value):
    with pytest.raises(SystemExit) as exited:
        main(["hx711-bridge", "--fake", "--port", "0", "--duration-s", value])
    assert exited.value.code == 2 and f"--duration-s: '{value}': expected a number > 0" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_bridge_command_stops_cleanly_on_ctrl_c_and_sigterm_with_its_summary(signum):
    command = [*BRIDGE_COMMAND, "--fake", "--host", "127.0.0.1", "--port", "0", "--json"]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as process:
        try:
            address = process.stderr.readline().split()[-1]
            with make_load_cell(LoadCellSettings(backend="tcp", address=address, **CAL)) as cell:
                cell.read(timeout_s=1.0)  # serving
            process.send_signal(signum)
            out, err = process.communicate(timeout=5.0)
        finally:
            process.kill()
    assert process.returncode == 0, err
    assert "interrupted" not in err and "Traceback" not in err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["address"] == address and summary["readings"] > 0


@pytest.mark.slow
def test_bridge_command_end_to_end():
    command = [
        sys.executable, "-c", "import sys; from teleop.cli import main; sys.exit(main(sys.argv[1:]))",
        "hx711-bridge", "--fake", "--force-n", "2.5", "--host", "127.0.0.1", "--port", "0",
        "--duration-s", "1.5", "--json",
    ]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as process:
        first = process.stderr.readline()
        assert "serving on tcp://127.0.0.1:" in first
        address = first.split()[-1]
        with make_load_cell(LoadCellSettings(backend="tcp", address=address, counts_per_n=42000.0, tare_counts=0)) as cell:
            forces = cell.read(timeout_s=1.0).value
        rest = process.stdout.read()
        assert process.wait(timeout=5.0) == 0
    assert len(forces) >= 1 and set(forces) == {2.5}  # 105000 counts / 42000 counts per N
    summary = json.loads(rest)  # stdout holds the summary alone
    assert summary["address"] == address and summary["readings"] > 10


def test_the_bridge_lets_go_of_hosts_that_left_while_the_source_was_silent():
    def silent() -> None:
        time.sleep(0.01)  # a source with nothing to report

    with Hx711Bridge(silent, host="127.0.0.1", port=0) as bridge:
        for _ in range(5):
            with make_load_cell(LoadCellSettings(backend="tcp", address=bridge.address, timeout_s=1.0)):
                pass
        deadline = time.monotonic() + 1.0
        while bridge.clients and time.monotonic() < deadline:
            time.sleep(0.01)
        assert bridge.clients == 0
