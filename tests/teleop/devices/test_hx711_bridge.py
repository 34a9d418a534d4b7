"""The bridge under hostile conditions: many or stalled hosts, accept failures, a garbled serial line."""

from __future__ import annotations

import errno
import json
import logging
import os
import resource
import socket
import threading
import time

import pytest

from teleop.cli import main
from teleop.devices.hx711 import STALL_S
from teleop.devices.hx711_bridge import Hx711Bridge, SerialCounts


def _fast_source() -> int:
    time.sleep(0.0005)
    return 1234


def _first_bytes(port: int, timeout_s: float = 2.0) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as sock:
        sock.settimeout(timeout_s)
        return sock.recv(200)


def test_a_host_whose_descriptor_is_above_1023_is_served():
    # select.select() refuses descriptors >= FD_SETSIZE (1024): it once killed the send thread for good
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1200:
        pytest.skip(f"the descriptor limit ({hard}) is too low to reach descriptor 1024")
    resource.setrlimit(resource.RLIMIT_NOFILE, (1200, hard))
    fillers: list[int] = []
    try:
        with Hx711Bridge(_fast_source, host="127.0.0.1", port=0) as bridge:
            null = os.open(os.devnull, os.O_RDONLY)
            fillers.append(null)
            while fillers[-1] < 1030:  # the next descriptors, the accepted host's among them, are above 1023
                fillers.append(os.dup(null))
            assert _first_bytes(bridge.port).startswith(b'{"v":1')
            assert _first_bytes(bridge.port).startswith(b'{"v":1')  # the send thread lives on
    finally:
        for fd in fillers:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_hosts_beyond_the_cap_are_refused_and_the_rest_served(caplog):
    with caplog.at_level(logging.WARNING), Hx711Bridge(_fast_source, host="127.0.0.1", port=0, max_clients=2) as bridge:
        held = [socket.create_connection(("127.0.0.1", bridge.port)) for _ in range(2)]
        try:
            deadline = time.monotonic() + 2.0
            while bridge.clients < 2 and time.monotonic() < deadline:
                time.sleep(0.01)
            with socket.create_connection(("127.0.0.1", bridge.port), timeout=2.0) as extra:
                extra.settimeout(2.0)
                assert extra.recv(200) == b""  # refused: closed at once
            deadline = time.monotonic() + 2.0  # counted, then logged, by the accepting thread
            while "already serving 2 hosts" not in caplog.text and time.monotonic() < deadline:
                time.sleep(0.01)
            assert bridge.refused == 1 and "already serving 2 hosts" in caplog.text
            assert held[0].recv(200).startswith(b'{"v":1')
        finally:
            for sock in held:
                sock.close()


def test_an_accept_failure_is_logged_and_accepting_goes_on(monkeypatch, caplog):
    real_accept = socket.socket.accept
    failed = []

    def accept_once_out_of_descriptors(self):
        if not failed:
            failed.append(True)
            raise OSError(errno.EMFILE, os.strerror(errno.EMFILE))
        return real_accept(self)

    monkeypatch.setattr(socket.socket, "accept", accept_once_out_of_descriptors)
    with caplog.at_level(logging.WARNING), Hx711Bridge(_fast_source, host="127.0.0.1", port=0) as bridge:
        assert _first_bytes(bridge.port).startswith(b'{"v":1')
        assert failed and bridge.accept_errors == 1
    assert "Too many open files" in caplog.text


def _flood_source() -> int:
    time.sleep(0.00005)  # ~20 kHz: a stalled host's socket buffers fill within a second or two
    return 1234


@pytest.mark.slow
def test_a_host_that_stops_reading_neither_stalls_the_others_nor_stays(caplog):
    with caplog.at_level(logging.INFO), Hx711Bridge(_flood_source, host="127.0.0.1", port=0) as bridge:
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
        stalled.connect(("127.0.0.1", bridge.port))
        good = socket.create_connection(("127.0.0.1", bridge.port))
        good.settimeout(5.0)
        try:
            start = last = time.monotonic()
            longest = 0.0
            while time.monotonic() - start < 8.0:
                assert good.recv(65536)
                now = time.monotonic()
                longest, last = max(longest, now - last), now
                if bridge.clients == 1 and now - start > 1.5:
                    break
            assert bridge.clients == 1, "the stalled host was never dropped"
            # Below the host's stall limit (a wait that long reads as a dead cell); 1 s per stalled host before.
            assert longest < STALL_S, f"the good host waited {longest:.2f} s on the stalled one"
            assert "dropped host" in caplog.text
        finally:
            stalled.close()
            good.close()


def test_a_serial_line_of_garbage_gives_the_loop_control_back_and_says_so(pty_pair, caplog):
    master, port = pty_pair
    source = SerialCounts(port)
    writing = threading.Event()
    writing.set()

    def garbage() -> None:  # a line that never pauses, never with a reading
        while writing.is_set():
            os.write(master, b"xx\n" * 50)
            time.sleep(0.001)

    writer = threading.Thread(target=garbage, daemon=True)
    writer.start()
    try:
        with caplog.at_level(logging.WARNING):
            start = time.monotonic()
            got: list = []
            caller = threading.Thread(target=lambda: got.extend(source() for _ in range(3)), daemon=True)
            caller.start()
            caller.join(2.0)  # it once never returned while garbage kept coming
            assert got == [None, None, None]
            assert time.monotonic() - start < 1.0  # the garbage budget each, not the idle timeout
        assert source.skipped["garbage"] >= 1
        assert "skipped a line (garbage, 1 so far)" in caplog.text
    finally:
        writing.clear()
        writer.join()
        source.close()


@pytest.mark.parametrize("value", ["1e308", "9e6"])
def test_bridge_command_refuses_noise_beyond_the_hx711_range(capsys, value):
    assert main(["hx711-bridge", "--fake", "--host", "127.0.0.1", "--port", "0", "--duration-s", "0.1",
                 "--noise-counts", value]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teleop hx711-bridge: error: --noise-counts ") and "8388608" in err


def test_bridge_command_warns_when_other_hosts_can_connect_and_keeps_stdout_for_json(capsys):
    assert main(["hx711-bridge", "--fake", "--port", "0", "--duration-s", "0.1", "--json"]) == 0  # 0.0.0.0
    captured = capsys.readouterr()
    warning = next(line for line in captured.err.splitlines() if "warning" in line)
    assert "tcp://0.0.0.0:" in warning and "without authentication" in warning and "--host 127.0.0.1" in warning
    assert json.loads(captured.out)["address"].startswith("tcp://0.0.0.0:")  # the summary alone


def test_bridge_command_on_loopback_gives_no_warning(capsys):
    assert main(["hx711-bridge", "--fake", "--host", "127.0.0.1", "--port", "0", "--duration-s", "0.1"]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err and captured.out == ""
