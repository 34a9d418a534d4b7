"""A folder of two simulated stress-ball records, ``kept.grasp`` and ``moved.grasp``, the second naming a
calibration file that is gone: what ``estimator evaluate``, ``compare`` and ``bench`` skip."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from teleop.catalogue import load_catalogue
from teleop.record import write_record
from teleop.settings import CONFIG_DIR, SensorSettings, load_settings
from teleop.sim.grasp import simulate_grasp


def records_with_a_gone_calibration(out: Path, *, seed: int, rename: bool = False,
                                    sensors: Callable[[SensorSettings], bool] = lambda s: True) -> tuple[Path, Path]:
    """(records folder, the missing calibration) under ``out``: ``moved.grasp``'s ``sensors`` name the
    missing file; with ``rename`` the objects are ``unseen_kept`` and ``unseen_moved`` (no shipped
    model trained on them)."""
    settings = load_settings()
    stress_ball = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "stress_ball")
    missing = out / "gone" / "calibration.npz"
    (out / "records").mkdir()
    for i, name in enumerate(("kept", "moved")):
        record, _ = simulate_grasp(stress_ball, settings=settings, rng=np.random.default_rng(seed + i), seed=seed + i)
        if rename:
            record = replace(record, label=replace(record.label, object_name=f"unseen_{name}"))
        if name == "moved":
            record = replace(record, sensors=tuple(replace(s, calibration=str(missing)) if sensors(s) else s
                                                   for s in record.sensors))
        write_record(record, out / "records" / f"{name}.grasp")
    return out / "records", missing
