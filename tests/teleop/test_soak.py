"""``teleop soak``: a few seconds of the grasp streams into a recorder process."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teleop.cli import main
from teleop.errors import SettingsError
from teleop.settings import load_settings
from teleop.soak import GRASP_RATES_HZ, LatencyHistogram, run_soak


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


@pytest.mark.parametrize(("duration_s", "warmup_s", "match"), [
    (0.0, None, "duration"), (float("nan"), None, "duration"), (5.0, 5.0, "warm-up"), (5.0, -1.0, "warm-up")])
def test_bad_soak_options_are_refused_naming_them(duration_s, warmup_s, match):
    with pytest.raises(SettingsError, match=match):
        run_soak(load_settings(), duration_s=duration_s, warmup_s=warmup_s)
