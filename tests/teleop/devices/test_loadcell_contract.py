"""One contract for every load-cell backend: sim replay, HX711 over a pty and over framed TCP, a real cell;
tare's edges on the sim cell."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from support.contract import assert_every_backend_covered, param_names
from support.threads import close_during_read

from teleop.devices.hx711_bridge import Hx711Bridge
from teleop.devices.loadcell import BACKENDS, LoadCell, make_load_cell
from teleop.devices.playback import GraspPlayback
from teleop.errors import (
    BackendNotFoundError,
    DeviceError,
    DeviceNotConnectedError,
    DeviceTimeoutError,
    InvalidCommandError,
)
from teleop.settings import LoadCellSettings

RATE_HZ = 80.0
N = 40
CALIBRATION = {"counts_per_n": 42_000.0, "tare_counts": 1234, "sample_rate_hz": RATE_HZ, "timeout_s": 1.0}


def _counts(seed: int = 5) -> list[int]:
    rng = np.random.default_rng(seed)
    return (1234 + np.round(np.linspace(0.0, 25.0, N) * 42_000 + rng.normal(0, 300, N))).astype(int).tolist()


def _newtons(counts: list[int]) -> np.ndarray:
    return (np.asarray(counts, dtype=np.float64) - 1234) / 42_000.0


@dataclass
class Rig:
    cell: LoadCell
    expected: np.ndarray | None  # the forces the source emits, None for real hardware
    start: Callable[[], None] = lambda: None
    cut: Callable[[], None] | None = None  # break the link under the cell, None where there is none


class ScriptedCounts:
    """A bridge source that, once released, emits its counts at RATE_HZ, then stays quiet."""

    def __init__(self, counts: list[int]):
        self.counts = list(counts)
        self.release = threading.Event()
        self._next_s: float | None = None

    def __call__(self) -> int | None:
        if not self.release.wait(0.05) or not self.counts:
            time.sleep(0.01)
            return None
        now = time.monotonic()
        self._next_s = now if self._next_s is None else self._next_s + 1.0 / RATE_HZ
        time.sleep(max(0.0, self._next_s - now))
        return self.counts.pop(0)


def _write_paced(master: int, lines: list[bytes]) -> None:
    start = time.monotonic()
    for i, line in enumerate(lines):  # on a fixed schedule, so a slow wake-up does not drift
        time.sleep(max(0.0, start + i / RATE_HZ - time.monotonic()))
        os.write(master, line)


# A backend's name runs the suite on it; "hardware" runs it on a real HX711 on a serial port.
PARAMS = ["sim", "serial", "tcp", pytest.param("hardware", marks=pytest.mark.hardware)]


def test_every_backend_in_the_table_runs_the_suite():
    assert_every_backend_covered("load cell", BACKENDS, param_names(PARAMS), fixture="rig",
                                 where="tests/teleop/devices/test_loadcell_contract.py")


@pytest.fixture(params=PARAMS)
def rig(request, make_record, hardware_env):
    cleanup = []
    if request.param == "sim":
        record = make_record(duration_s=N / RATE_HZ, force_hz=RATE_HZ)
        playback = GraspPlayback(record)
        rig = Rig(make_load_cell(LoadCellSettings(**CALIBRATION), playback=playback), record.force_n.value, playback.start)
    elif request.param == "serial":
        master, port = request.getfixturevalue("pty_pair")
        counts = _counts()
        lines = [b"23\r\n"] + [b"%d\r\n" % c for c in counts]  # opened mid-line: "23" ends a reading
        writer = threading.Thread(target=_write_paced, args=(master, lines), daemon=True)
        cell = make_load_cell(LoadCellSettings(backend="serial", port=port, **CALIBRATION))
        rig = Rig(cell, _newtons(counts), writer.start, lambda: os.close(master))
        cleanup.append(lambda: writer.join(timeout=2.0) if writer.is_alive() else None)
    elif request.param == "tcp":
        source = ScriptedCounts(_counts())
        bridge = Hx711Bridge(source, host="127.0.0.1", port=0).start()
        cleanup.append(bridge.close)
        cell = make_load_cell(LoadCellSettings(backend="tcp", address=bridge.address, **CALIBRATION))

        def start():
            deadline = time.monotonic() + 2.0
            while bridge.clients == 0 and time.monotonic() < deadline:  # the accept thread registers it
                time.sleep(0.005)
            source.release.set()

        rig = Rig(cell, _newtons(source.counts), start, bridge.close)
    else:
        port = hardware_env("COMPLIANCE_TELEOP_HX711_PORT")
        rig = Rig(make_load_cell(LoadCellSettings(backend="serial", port=port, timeout_s=1.0)), None)
    yield rig
    rig.cell.close()
    for step in cleanup:
        step()


def _collect(cell: LoadCell, n: int):
    t, v = [], []
    while len(v) < n:
        samples = cell.read(timeout_s=1.0)
        t.extend(samples.t_s)
        v.extend(samples.value)
    return np.array(t), np.array(v)


def test_unconnected_and_closed_cells_refuse_calls(rig):
    with pytest.raises(DeviceNotConnectedError, match="connect"):
        rig.cell.read()
    with pytest.raises(DeviceNotConnectedError):
        rig.cell.tare()
    with rig.cell:
        assert rig.cell.connected
    with pytest.raises(DeviceNotConnectedError, match="closed"):
        rig.cell.read()


def test_every_sample_arrives_in_order_in_newtons(rig):
    with rig.cell:
        rig.start()
        t, v = _collect(rig.cell, N)
    assert np.all(np.diff(t) >= 0)
    assert np.median(np.diff(t)) == pytest.approx(1.0 / RATE_HZ, rel=0.4)
    assert np.all(np.isfinite(v))
    if rig.expected is not None:
        np.testing.assert_allclose(v, rig.expected, rtol=0, atol=1e-12)


def test_tare_zeroes_with_the_samples_it_saw_and_keeps_the_rest(rig):
    with rig.cell:
        rig.start()
        offset = rig.cell.tare(n_samples=8)
        t, v = _collect(rig.cell, N - 8)
    if rig.expected is not None:
        assert offset == pytest.approx(rig.expected[:8].mean(), abs=1e-12)
        np.testing.assert_allclose(v, rig.expected[8:] - offset, rtol=0, atol=1e-12)
    with pytest.raises(InvalidCommandError, match="n_samples"):
        rig.cell.connect().tare(n_samples=0)


@contextlib.contextmanager
def _read_out(rig, *, skip_unless: object, why: str):
    """The cell connected and its recording read out: it sends nothing more (skipped when
    ``skip_unless`` is None, saying ``why``)."""
    if skip_unless is None:
        pytest.skip(why)
    with rig.cell:
        rig.start()
        _collect(rig.cell, N)
        yield rig.cell


def test_a_silent_source_times_out(rig):
    with _read_out(rig, skip_unless=rig.expected, why="a real cell does not fall silent on request") as cell:
        started = time.monotonic()
        with pytest.raises(DeviceTimeoutError, match="no force sample within 0.2 s"):
            cell.read(timeout_s=0.2)
        assert time.monotonic() - started >= 0.19


def test_close_wakes_a_read_waiting_in_another_thread(rig):
    with _read_out(rig, skip_unless=rig.expected, why="a real cell does not fall silent on request") as cell:
        ended = close_during_read(lambda: cell.read(timeout_s=3.0), cell.close, errors=DeviceError, waiting_s=0.2)
    # Woken by close(), not by the 3 s timeout: bounded well below it, as a loaded machine is slow.
    assert isinstance(ended.outcome, DeviceNotConnectedError) and ended.ended_s < 2.0


def test_a_link_that_fails_wakes_a_waiting_read(rig):
    with _read_out(rig, skip_unless=rig.cut, why="this backend has no link to cut") as cell:
        ended = close_during_read(lambda: cell.read(timeout_s=3.0), rig.cut, errors=DeviceError, waiting_s=0.2)
    error = ended.outcome
    assert isinstance(error, DeviceError) and not isinstance(error, DeviceTimeoutError | DeviceNotConnectedError)
    assert "link failed" in str(error) and ended.ended_s < 2.0  # well below the 3 s timeout: woken by the cut


def test_a_reconnected_cell_hands_out_nothing_from_before_the_close(make_record):
    record = make_record(duration_s=N / RATE_HZ, force_hz=RATE_HZ)
    playback = GraspPlayback(record)
    cell = make_load_cell(LoadCellSettings(**CALIBRATION), playback=playback)
    playback.start(t0_s=time.monotonic() - 10.0)  # every sample is due at once: tare leaves N - 1 over
    with cell:
        cell.tare(n_samples=1)
    with cell, pytest.raises(DeviceTimeoutError):
        cell.read(timeout_s=0.2)


# --------------------------------------------------------------------------- tare, on the sim cell


class FakeClock:
    def __init__(self, now: float = 1000.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


def _sim_cell(make_record, clock=time.monotonic):
    """A sim cell replaying N samples at RATE_HZ on ``clock``, its playback (not started) and the forces."""
    record = make_record(duration_s=N / RATE_HZ, force_hz=RATE_HZ)
    playback = GraspPlayback(record, clock=clock)
    return make_load_cell(LoadCellSettings(**CALIBRATION), playback=playback), playback, record.force_n


def test_samples_tare_took_beyond_its_count_come_out_of_the_next_read(make_record):
    cell, playback, forces = _sim_cell(make_record)
    playback.start(t0_s=time.monotonic() - 10.0)  # the whole record is due at once
    with cell:
        offset = cell.tare(n_samples=3)
        rest = cell.read(timeout_s=0.5)
    assert offset == pytest.approx(forces.value[:3].mean(), abs=1e-12)
    np.testing.assert_allclose(rest.value, forces.value[3:] - offset, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rest.t_s, playback.live_time(forces.t_s[3:]), rtol=0, atol=1e-9)


def test_samples_tare_left_over_come_before_the_fresh_ones(make_record):
    clock = FakeClock()
    cell, playback, forces = _sim_cell(make_record, clock)
    playback.start(t0_s=1000.0)
    clock.now = 1000.0 + 4.5 / RATE_HZ  # samples 0..4 due
    with cell:
        offset = cell.tare(n_samples=2)
        clock.now = 1000.0 + 8.5 / RATE_HZ  # samples 5..8 due as well
        got = cell.read(timeout_s=0.5)
    assert np.all(np.diff(got.t_s) > 0)
    np.testing.assert_allclose(got.value, forces.value[2:9] - offset, rtol=0, atol=1e-12)


def test_the_default_tare_averages_a_quarter_second_of_samples(make_record):
    cell, playback, forces = _sim_cell(make_record)
    playback.start(t0_s=time.monotonic() - 10.0)
    window = round(0.25 * RATE_HZ)  # 20 samples at 80 Hz
    with cell:
        offset = cell.tare()
        rest = cell.read(timeout_s=0.5)
    assert offset == pytest.approx(forces.value[:window].mean(), abs=1e-12)
    assert len(rest) == N - window


def test_a_tare_that_gets_exactly_its_count_in_one_batch_returns_at_once(make_record):
    clock = FakeClock()
    cell, playback, forces = _sim_cell(make_record, clock)
    playback.start(t0_s=1000.0)
    clock.now = 1000.0 + 4.5 / RATE_HZ  # samples 0..4 due, nothing more until the clock moves
    with cell:
        offset = cell.tare(n_samples=5, timeout_s=0.3)  # no wait for a sixth sample
    assert offset == pytest.approx(forces.value[:5].mean(), abs=1e-12)


def test_closing_during_a_tare_says_the_cell_was_closed(make_record):
    cell, _, _ = _sim_cell(make_record)  # the replay never starts: the cell stays silent
    cell.connect()
    ended = close_during_read(lambda: cell.tare(timeout_s=3.0), cell.close, errors=DeviceError, waiting_s=0.2)
    assert isinstance(ended.outcome, DeviceNotConnectedError)
    assert "was closed" in str(ended.outcome)


@pytest.mark.parametrize("n_samples", [True, 2.0])
def test_tare_refuses_a_sample_count_that_is_not_a_whole_number(make_record, n_samples):
    cell, playback, _ = _sim_cell(make_record)
    playback.start(t0_s=time.monotonic() - 10.0)
    with cell, pytest.raises(InvalidCommandError, match=rf"n_samples = {n_samples!r}: expected an integer >= 1"):
        cell.tare(n_samples=n_samples)


def test_unknown_backend_lists_the_names():
    with pytest.raises(BackendNotFoundError) as info:
        make_load_cell(LoadCellSettings(), backend="bluetooth")
    assert all(name in str(info.value) for name in BACKENDS)
