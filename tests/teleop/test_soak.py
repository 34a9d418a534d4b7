"""``teleop soak``: a few seconds of the grasp streams into a recorder process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import teleop.soak as soak
from teleop.cli import main
from teleop.errors import BusTimeoutError, SettingsError
from teleop.settings import load_settings
from teleop.soak import GRASP_RATES_HZ, LatencyHistogram, check_log_path, run_soak


@pytest.mark.slow
def test_soak_command_loses_nothing_and_reports_latency_and_memory(capsys):
    assert main(["soak", "--minutes", "0.05", "--warmup-s", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["lost_grasp_msgs"] == 0 and result["send_timeouts"] == 0 and result["gaps"] == 0
    assert result["received"] == result["sent"]
    for topic, rate in GRASP_RATES_HZ.items():  # on schedule: 3 s at each rate
        assert abs(result["sent"][topic] - 3 * rate) <= 1, topic
    assert 0 < result["p50_ms"] <= result["p99_ms"] <= result["max_ms"] * 1.01
    assert result["rss_warm_mb"] > 10 and result["rss_growth_mb"] == pytest.approx(
        result["rss_end_mb"] - result["rss_warm_mb"], abs=1e-2)
    assert result["log_bytes"] > result["sent"]["frame/left"] * result["frame_bytes_mean"]  # frames were stored
    assert result["recorder_error"] is None and result["frame_bytes_mean"] > 10_000  # camera-sized JPEGs


def test_latency_histogram_quantiles_are_within_its_resolution():
    values = np.random.default_rng(0).lognormal(0.0, 1.0, 5000)
    histogram = LatencyHistogram()
    for value in values:
        histogram.add(float(value))
    for q in (0.5, 0.99):
        exact = np.quantile(values, q)
        assert exact <= histogram.quantile_ms(q) <= exact * 1.011
    assert histogram.count == 5000 and histogram.max_ms == values.max()
    assert LatencyHistogram().quantile_ms(0.5) is None
    one = LatencyHistogram()
    one.add(0.437)  # a bin's upper edge lies above it: a quantile never says more than the largest value
    assert one.quantile_ms(0.5) == one.quantile_ms(0.99) == one.max_ms == 0.437


def test_a_latency_quantile_is_at_most_one_resolution_above_the_reading_it_reaches():
    # the upper edge of the reading's own bin, not of the next one
    values = np.random.default_rng(1).lognormal(1.0, 0.8, 4000)
    histogram = LatencyHistogram(resolution=0.005)
    for value in values:
        histogram.add(float(value))
    ordered = np.sort(values)
    for q in (0.1, 0.5, 0.9, 0.99):
        reached = ordered[int(np.ceil(q * len(values))) - 1]  # the reading the q-th fraction of readings reach
        assert reached <= histogram.quantile_ms(q) <= reached * 1.005 * (1 + 1e-12), q


@pytest.mark.slow  # the recorder process takes seconds to start
def test_messages_whose_send_timed_out_count_as_lost(monkeypatch):
    send = soak._send
    refused = []

    def send_timing_out_three_widths(publisher, topic, n, t_s, frames):
        if topic == "width" and len(refused) < 3:
            refused.append(n)
            raise BusTimeoutError("simulated send timeout")
        send(publisher, topic, n, t_s, frames)

    monkeypatch.setattr(soak, "_send", send_timing_out_three_widths)
    result = run_soak(load_settings(), duration_s=0.5, warmup_s=0.0)
    assert result.send_timeouts == 3 and result.received == result.sent  # the rest delivered
    assert result.lost_grasp_msgs == 3


@pytest.mark.parametrize(("duration_s", "warmup_s", "match"), [
    (0.0, None, "duration"), (float("nan"), None, "duration"), (6e-8, None, "at least 0.1 s"), (5.0, 5.0, "warm-up"),
    (5.0, -1.0, "warm-up")])
def test_bad_soak_options_are_refused_naming_them(duration_s, warmup_s, match):
    with pytest.raises(SettingsError, match=match):
        run_soak(load_settings(), duration_s=duration_s, warmup_s=warmup_s)


@pytest.mark.parametrize(("where", "expected"), [
    ("missing/x.mcap", "its folder {tmp}/missing does not exist"),
    ("file/x.mcap", "its folder {tmp}/file is not a folder"),
    ("file", "exists: name a new file"),
])
def test_a_log_that_cannot_be_created_is_refused_in_one_line_before_the_consumer_starts(
        tmp_path, capsys, where, expected):
    (tmp_path / "file").write_text("taken")
    log = tmp_path / where
    assert main(["soak", "--minutes", "0.02", "--log", str(log)]) == 2
    err = capsys.readouterr().err
    assert err == f"teleop soak: error: --log {log}{'' if where == 'file' else ':'} {expected.format(tmp=tmp_path)}\n"
    with pytest.raises(SettingsError, match="does not exist"):  # the function checks it too
        run_soak(load_settings(), duration_s=1.0, log_path=tmp_path / "missing" / "x.mcap")


def test_a_dangling_link_at_the_log_path_is_refused_as_existing(tmp_path):
    # recording through it would create a file wherever it points
    link = tmp_path / "soak.mcap"
    link.symlink_to(tmp_path / "elsewhere" / "target.mcap")
    with pytest.raises(SettingsError, match="exists: name a new file"):
        check_log_path(link)


def _spawned_children(pid: int) -> list[int]:
    """Processes ``pid`` started with multiprocessing's spawn (the consumer, not its resource tracker)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            command = (stat.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if parent == pid and b"spawn_main" in command:
            found.append(int(stat.parent.name))
    return found


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow
def test_sigterm_stops_the_soak_as_ctrl_c_does_consumer_and_temporary_log_gone(tmp_path):
    command = [sys.executable, "-c", "import sys; from teleop.cli import main; sys.exit(main(sys.argv[1:]))",
               "soak", "--minutes", "0.5"]
    # The temporary log goes under TMPDIR: here, so that what is left of it can be seen.
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    with subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=env) as process:
        try:
            deadline = time.monotonic() + 15.0
            while not list(tmp_path.glob("soak-*/soak.mcap")):  # the consumer is recording
                assert process.poll() is None and time.monotonic() < deadline, "the soak did not start"
                time.sleep(0.05)
            consumers = _spawned_children(process.pid)
            assert len(consumers) == 1, consumers
            process.send_signal(signal.SIGTERM)
            err = process.communicate(timeout=5.0)[1]
        finally:
            process.kill()
    assert process.returncode == 143 and err.rstrip().endswith("teleop soak: terminated"), err
    assert "Traceback" not in err and "leaked" not in err
    assert not any(_running(pid) for pid in consumers)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("minutes", "expected"), [
    ("0", "--minutes 0: expected at least 0.0017 (0.1 s)"),
    ("-1", "--minutes -1: expected at least 0.0017 (0.1 s)"),
    ("nan", "--minutes nan: expected a finite number of at least 0.0017 (0.1 s)"),
])
def test_a_bad_minutes_is_refused_naming_the_option_in_its_unit(capsys, minutes, expected):
    assert main(["soak", "--minutes", minutes]) == 2
    assert capsys.readouterr().err == f"teleop soak: error: {expected}\n"
