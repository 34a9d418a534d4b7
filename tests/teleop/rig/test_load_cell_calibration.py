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

import numpy as np
import pytest

from teleop.cli import main
from teleop.errors import DeviceStalledError
from teleop.rig import load_cell_calibration
from teleop.rig.load_cell_calibration import G_M_S2, Level, fit_load_cell
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

    def ask(prompt: str) -> str:
        prompts.append(prompt)
        answer = next(answers)
        if answer:
            firmware.place(float(answer))
            time.sleep(0.3)  # the person lets go before pressing Enter
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
