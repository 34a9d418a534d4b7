"""``teleop calibrate load-cell`` end to end: the serial HX711 backend over a pseudo-terminal.

A fake firmware thread writes the serial line protocol (one decimal count per line, 80 Hz)
into the pty's master side: ``counts = tare + c F (1 + beta F) + noise``, where F is the
weight of the mass the test "places" on a timer (ramping in over 0.2 s, as a hand sets it
down). The command reads the slave side through the ``serial`` backend, as it would
``/dev/ttyUSB0``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import threading
import time
import tty
from types import SimpleNamespace

import numpy as np
import pytest

from teleop.cli import main
from teleop.errors import DeviceStalledError, DeviceTimeoutError, SettingsError, TeleopError
from teleop.rig import load_cell_calibration
from teleop.rig.load_cell_calibration import (
    G_M_S2,
    Level,
    fit_load_cell,
    read_level,
    wait_for_level,
)
from teleop.settings import default_settings_path, load_settings
from teleop.settings_edit import update_settings_file

TARE = -51234
COUNTS_PER_N = 41873.2


class FakeFirmware:
    """An Arduino HX711 bridge: ``schedule`` is [(seconds after start, mass in g on the cell)]."""

    def __init__(self, master: int, schedule: list[tuple[float, float]], *, beta_per_n: float = 0.0,
                 noise_counts: float = 30.0, rate_hz: float = 80.0):
        self.master, self.schedule, self.beta, self.noise = master, schedule, beta_per_n, noise_counts
        self.period_s = 1.0 / rate_hz
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.start_s = time.monotonic()
        self.thread.start()

    def mass_g(self, t: float) -> float:
        mass, before = 0.0, 0.0
        for at, grams in self.schedule:
            if t >= at:
                mass, before = grams, mass
                if t < at + 0.2:  # being set down
                    return before + (grams - before) * (t - at) / 0.2
        return mass

    def _run(self) -> None:
        rng = np.random.default_rng(1)
        while not self.stop.wait(self.period_s):
            force = self.mass_g(time.monotonic() - self.start_s) * 1e-3 * G_M_S2
            counts = TARE + COUNTS_PER_N * force * (1.0 + self.beta * force) + rng.normal(0.0, self.noise)
            os.write(self.master, b"%d\r\n" % round(counts))

    def place(self, mass_g: float) -> None:
        """A person sets ``mass_g`` on the cell now."""
        self.schedule.append((time.monotonic() - self.start_s, mass_g))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=2.0)


@pytest.fixture
def serial_rig(tmp_path):
    """(settings file with a serial cell on a pty, pty master fd)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "serial", "load_cell.port": os.ttyname(slave)})
    yield path, master
    os.close(master)
    os.close(slave)


def _calibrate(path, masses, capsys) -> tuple[int, dict]:
    argv = ["calibrate", "load-cell", "--settings", str(path), "--average-s", "0.5", "--settle-s", "0.3",
            "--place-timeout-s", "5", "--json"]
    for mass in masses:
        argv += ["--mass-g", str(mass)]
    code = main(argv)
    return code, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.slow
def test_recovers_tare_and_counts_per_newton_and_writes_them(serial_rig, capsys):
    path, master = serial_rig
    before = path.read_text()
    firmware = FakeFirmware(master, [(1.5, 200.0), (3.0, 500.0), (4.5, 1000.0)])
    try:
        code, result = _calibrate(path, [200, 500, 1000], capsys)
    finally:
        firmware.close()
    assert code == 0, result
    assert result["counts_per_n"] == pytest.approx(COUNTS_PER_N, rel=0.01)
    assert result["tare_counts"] == pytest.approx(TARE, abs=10)
    assert result["residual_fraction"] < 0.001 and [lv["mass_g"] for lv in result["levels"]] == [0, 200, 500, 1000]
    settings = load_settings(path)
    assert settings.load_cell.counts_per_n == pytest.approx(COUNTS_PER_N, rel=0.01)
    assert settings.load_cell.tare_counts == pytest.approx(TARE, abs=10)
    assert {c["key"] for c in result["changes"]} == {"load_cell.tare_counts", "load_cell.counts_per_n"}
    assert [ln for ln in before.splitlines() if ln.startswith("#")] == \
           [ln for ln in path.read_text().splitlines() if ln.startswith("#")]


@pytest.mark.slow
def test_a_non_linear_cell_is_refused_with_the_reason(serial_rig, capsys):
    path, master = serial_rig
    before = path.read_bytes()
    firmware = FakeFirmware(master, [(1.5, 200.0), (3.0, 1000.0)], beta_per_n=0.02)  # +20 % at 10 N
    try:
        code, result = _calibrate(path, [200, 1000], capsys)
    finally:
        firmware.close()
    assert code == 1 and not result["ok"]
    assert result["reason"].startswith("non-linear") and "of full scale" in result["reason"]
    assert path.read_bytes() == before


@pytest.mark.slow
def test_a_mass_never_placed_times_out_naming_what_to_do(serial_rig, capsys):
    path, master = serial_rig
    firmware = FakeFirmware(master, [])
    try:
        code = main(["calibrate", "load-cell", "--settings", str(path), "--mass-g", "100", "--average-s", "0.3",
                     "--place-timeout-s", "1"])
    finally:
        firmware.close()
    assert code == 2
    assert "no new load within 1 s" in capsys.readouterr().err


def test_a_serial_cell_without_pyserial_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "serial", None)  # `import serial` raises ImportError, as when not installed
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "serial", "load_cell.port": "/dev/ttyUSB9"})
    assert main(["calibrate", "load-cell", "--settings", str(path), "--mass-g", "100"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teleop calibrate: error: load cell backend 'serial' cannot be loaded")
    assert err.rstrip().endswith("(install the 'robot' extra)") and len(err.splitlines()) == 1


@pytest.mark.parametrize("option", ["--average-s", "--place-timeout-s"])
@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_times_that_are_not_positive_are_refused_before_reading(option, value, tmp_path, capsys):
    # --average-s 0 read no level and ended in a "signal wires swapped" refusal.
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "load-cell", "--settings", str(tmp_path / "rig.toml"), option, value])
    assert exited.value.code == 2
    assert f"argument {option}: '{value}': expected a number > 0" in capsys.readouterr().err


@pytest.mark.slow
def test_interactive_run_asks_for_each_mass(serial_rig, capsys, monkeypatch):
    path, master = serial_rig
    firmware = FakeFirmware(master, [])
    answers = iter(["", "250", "750", ""])  # Enter at the tare, two masses, then done
    prompts = []
    cells = []
    connect = load_cell_calibration.connect_counts_cell
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda s: cells.append(connect(s)) or cells[-1])

    def let_go(mass_g: float) -> None:
        """Read the cell until it shows the whole mass: every reading from before is then consumed,
        however late the threads ran (a person waits for the display to settle before pressing Enter)."""
        full_counts = TARE + COUNTS_PER_N * mass_g * 1e-3 * G_M_S2
        for _ in range(1000):  # a bound, not a wait: each read blocks until readings arrive
            if abs(cells[0].read().value[-1] - full_counts) < 10 * firmware.noise:
                return
        raise AssertionError(f"the cell never showed the {mass_g:g} g placed")

    def ask(prompt: str) -> str:
        prompts.append(prompt)
        answer = next(answers)
        if answer:
            firmware.place(float(answer))
            let_go(float(answer))
        return answer

    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    args = argparse.Namespace(settings=str(path), mass_g=None, average_s=0.5, settle_s=0.3, place_timeout_s=5.0,
                              max_residual_percent=1.0, max_noise_percent=0.5, json=False)
    try:
        code = load_cell_calibration.run(args, ask=ask)
    finally:
        firmware.close()
    assert code == 0 and prompts[0].startswith("Remove everything from the cell") and len(prompts) == 4
    assert load_settings(path).load_cell.counts_per_n == pytest.approx(COUNTS_PER_N, rel=0.01)
    assert "load_cell.counts_per_n: 42000.0 -> " in capsys.readouterr().out


def _level(mass_g: float, counts: float, std: float = 5.0) -> Level:
    return Level(mass_g, counts, std, 100)


@pytest.mark.parametrize("loaded, start", [
    ([_level(500.0, 1000.0 + 3.0)], "the 500 g mass reads no change"),
    ([_level(500.0, 1000.0 - 2e5)], "the counts fall under load"),
    ([_level(500.0, 1000.0 + 2e5, std=5000.0)], "noisy"),
])
def test_refusals(loaded, start):
    fit = fit_load_cell(_level(0.0, 1000.0), loaded)
    assert not fit and fit.reason.startswith(start)


def test_a_linear_cell_fits_exactly():
    force = np.array([1.0, 2.0, 5.0]) * G_M_S2
    fit = fit_load_cell(_level(0.0, 100.0), [_level(m * 1000, 100.0 + 4e4 * f) for m, f in zip([1, 2, 5], force,
                                                                                                strict=True)])
    assert fit and fit.counts_per_n == pytest.approx(4e4) and fit.residual_n == pytest.approx(0.0, abs=1e-9)
    assert fit.full_scale_n == pytest.approx(5 * G_M_S2)


def test_a_stalled_cell_during_a_level_says_what_to_check():
    class Stalled:
        settings = load_settings(default_settings_path()).load_cell

        def read(self, timeout_s=None):
            raise DeviceStalledError("<SerialHx711 /dev/ttyUSB0>: no valid reading for 0.5 s: silent: nothing arrived")

    with pytest.raises(DeviceStalledError, match="silent: nothing arrived: check the cable, the bridge and the setting"):
        load_cell_calibration.read_level(Stalled(), 100.0, duration_s=0.01)


@pytest.fixture
def no_cell(monkeypatch):
    """The cell's connections: a refusal must come before the first (before anyone tares or places a mass)."""
    connected = []

    def connect(settings):
        connected.append(settings)
        raise AssertionError("the load cell was connected to")

    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", connect)
    return connected


@pytest.mark.parametrize("option, value, expected", [
    ("--mass-g", "inf", "expected a number > 0"),  # passed the mass check, waited for the mass, fitted NaN
    ("--mass-g", "nan", "expected a number > 0"),
    ("--mass-g", "-5", "expected a number > 0"),
    ("--settle-s", "-1", "expected a number >= 0"),  # time.sleep's traceback after the masses were placed
    ("--settle-s", "nan", "expected a number >= 0"),
    ("--settle-s", "inf", "expected a number >= 0"),
    ("--max-residual-percent", "nan", "expected a number > 0"),  # silently switched the check off
    ("--max-residual-percent", "-1", "expected a number > 0"),  # refused every cell
    ("--max-noise-percent", "nan", "expected a number > 0"),
    ("--max-noise-percent", "-1", "expected a number > 0"),
])
def test_bad_numbers_are_refused_before_the_cell_is_read(option, value, expected, tmp_path, capsys, no_cell):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    argv = ["calibrate", "load-cell", "--settings", str(path), option, value]
    if option != "--mass-g":
        argv += ["--mass-g", "100"]
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2 and not no_cell
    assert f"argument {option}: '{value}': {expected}" in capsys.readouterr().err


def test_a_settle_time_of_zero_is_accepted(tmp_path, no_cell):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    with pytest.raises(AssertionError, match="the load cell was connected to"):
        main(["calibrate", "load-cell", "--settings", str(path), "--mass-g", "100", "--settle-s", "0"])


def test_a_read_only_settings_file_is_refused_before_the_cell_is_read(tmp_path, capsys, no_cell):
    # It was rewritten anyway (os.replace does not ask the file's mode), root or not.
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    path.chmod(0o444)
    before = path.read_bytes()
    assert main(["calibrate", "load-cell", "--settings", str(path), "--mass-g", "100"]) == 2
    err = capsys.readouterr().err
    assert f"error: settings file {path} is read-only (mode 444)" in err and len(err.splitlines()) == 1
    assert not no_cell and path.read_bytes() == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into any folder: nothing to refuse")
def test_a_settings_folder_that_cannot_be_written_is_refused_before_the_cell_is_read(tmp_path, capsys, no_cell):
    # The whole measurement ran, then the temporary file could not be made: a PermissionError traceback.
    folder = tmp_path / "rig"
    folder.mkdir()
    path = folder / "rig.toml"
    shutil.copy(default_settings_path(), path)
    folder.chmod(0o555)
    try:
        assert main(["calibrate", "load-cell", "--settings", str(path), "--mass-g", "100"]) == 2
    finally:
        folder.chmod(0o755)
    assert f"error: cannot write settings file {path}: permission denied to its folder" in capsys.readouterr().err
    assert not no_cell


@pytest.mark.parametrize("answer", ["inf", "nan", "0"])
def test_an_interactive_mass_that_is_not_finite_and_positive_is_asked_again(answer, capsys, monkeypatch):
    read = []
    monkeypatch.setattr(load_cell_calibration, "read_level", lambda *a, **k: read.append(a))
    answers = iter([answer, ""])
    assert load_cell_calibration._interactive_levels(None, argparse.Namespace(average_s=0.5),
                                                     lambda _prompt: next(answers)) == []
    assert not read and f"not a finite mass > 0 g: {answer!r}" in capsys.readouterr().err


SLOPE = 4.0e4  # counts per N


def _at(mass_g: float, *, miss_n: float = 0.0, std: float = 5.0) -> Level:
    """The level of a cell of SLOPE counts per N that reads ``miss_n`` more than ``mass_g`` weighs."""
    return Level(mass_g, 1000.0 + SLOPE * (mass_g * 1e-3 * G_M_S2 + miss_n), std, 100)


class ChunkCell:
    """A counts cell: each read() returns the next chunk of ``chunks`` (the last one repeats)."""

    settings = load_settings(default_settings_path()).load_cell

    def __init__(self, *chunks):
        self.chunks = [np.asarray(c, dtype=np.float64) for c in chunks]
        self.reads = 0
        self.loaded = None  # (loaded chunk) once a mass is placed: see placing()

    def read(self, timeout_s=None):
        if self.loaded is not None:
            return argparse.Namespace(value=self.loaded)
        chunk = self.chunks[min(self.reads, len(self.chunks) - 1)]
        self.reads += 1
        return argparse.Namespace(value=chunk)

    def close(self):
        pass


def placing(monkeypatch, cell, loaded):
    """The person places the mass when told to (``say("place ...")``): the cell reads ``loaded`` from then on."""
    def say(text):
        if text.startswith("place "):
            cell.loaded = np.asarray(loaded, dtype=np.float64)
    monkeypatch.setattr(load_cell_calibration, "say", say)


def test_no_masses_is_an_error_naming_the_masses():
    with pytest.raises(TeleopError, match="expected at least one"):
        fit_load_cell(_at(0.0), [])


def test_noise_is_judged_against_its_own_limit_not_the_linearity_limit():
    # 500 g: 4.9 N full scale; single readings scatter 0.75 % of it: above the 0.5 % noise limit,
    # below the 1 % residual limit.
    noise_counts = 0.0075 * 0.5 * G_M_S2 * SLOPE
    fit = fit_load_cell(_at(0.0, std=noise_counts), [_at(500.0, std=noise_counts)])
    assert not fit and fit.reason.startswith("noisy")
    assert fit_load_cell(_at(0.0, std=noise_counts), [_at(500.0, std=noise_counts)], max_noise_fraction=0.01)


def test_a_miss_under_the_linearity_limit_is_accepted_and_reported_as_a_fraction_of_full_scale():
    full_scale = 1.0 * G_M_S2
    # The 200 g mass reads 0.8 % of full scale high: the line through the tare misses by ~0.75 % of it.
    fit = fit_load_cell(_at(0.0), [_at(200.0, miss_n=0.008 * full_scale), _at(1000.0)])
    assert fit, fit.reason  # 0.75 % is under the default 1 % (and over the 0.5 % noise limit)
    assert 0.005 < fit.residual_fraction < 0.01
    assert fit.residual_fraction == pytest.approx(fit.residual_n / full_scale)
    assert not fit_load_cell(_at(0.0), [_at(200.0, miss_n=0.03 * full_scale), _at(1000.0)])


def test_one_reading_off_the_level_does_not_count_as_a_mass_placed():
    # The median of the last three readings must depart: a single spike is not a placed mass.
    cell = ChunkCell([0.0, 0.0, 5000.0])
    with pytest.raises(DeviceTimeoutError, match="no new load within"):
        wait_for_level(cell, Level(0.0, 0.0, 1.0, 100), 20.0, timeout_s=0.05)
    wait_for_level(ChunkCell([0.0, 5000.0, 5000.0]), Level(0.0, 0.0, 1.0, 100), 20.0, timeout_s=0.05)


def test_a_level_drops_the_readings_queued_before_it():
    cell = ChunkCell([0.0] * 40, [1000.0, 1002.0])  # the tare still queued, then the mass
    level = read_level(cell, 100.0, duration_s=0.0)
    assert level.mean_counts == pytest.approx(1001.0) and level.n == 2


def _args(**kw):
    base = dict(settings="unused", mass_g=[100.0], average_s=0.01, settle_s=0.25, place_timeout_s=0.05,
                max_residual_percent=1.0, max_noise_percent=0.5, json=False)
    return argparse.Namespace(**{**base, **kw})


def test_each_placed_mass_is_let_settle_for_settle_s(monkeypatch):
    slept = []
    # The module's time alone: patching time.sleep itself would take other threads' sleeps too.
    monkeypatch.setattr(load_cell_calibration, "time", SimpleNamespace(sleep=slept.append, monotonic=time.monotonic))
    cell = ChunkCell([0.0, 1.0, 2.0])
    placing(monkeypatch, cell, [50000.0, 50000.0, 50000.0])
    load_cell_calibration._measure(cell, _args(), ask=lambda _p: "")
    assert slept == [0.25]


def test_a_noisy_tare_raises_the_step_a_mass_must_make(monkeypatch):
    # Tare readings scatter by ~100 counts std: a 60-count step is not a mass placed (10 x the noise std).
    cell = ChunkCell([0.0, 100.0, -100.0])
    placing(monkeypatch, cell, [60.0, 60.0, 60.0])
    with pytest.raises(DeviceTimeoutError, match="no new load within"):
        load_cell_calibration._measure(cell, _args(), ask=lambda _p: "")


def test_no_masses_and_no_terminal_is_refused_before_the_cell_is_read(absent_cell_rig, capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin.isatty", lambda: False)
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell",
                        lambda s: (_ for _ in ()).throw(AssertionError("the load cell was connected to")))
    assert main(["calibrate", "load-cell", "--settings", str(absent_cell_rig)]) == 2
    assert "no --mass-g given and no terminal to ask in" in capsys.readouterr().err


def test_an_interactive_run_with_no_mass_says_one_is_needed(absent_cell_rig, monkeypatch):
    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda s: ChunkCell([0.0, 1.0, 2.0]))
    before = absent_cell_rig.read_bytes()
    with pytest.raises(SettingsError, match="no mass was measured"):
        load_cell_calibration.run(_args(settings=str(absent_cell_rig), mass_g=None), ask=lambda _p: "")
    assert absent_cell_rig.read_bytes() == before
