"""A model's inputs on one fixed grasp, recorded at training time and checked since.

A model learned the inputs the measurement code produced when its data set was
built. Rather than hashing that code's source (a comment edit would force a
retrain), a model records :data:`~estimator.inference.inputs.MEASUREMENT_VERSION`
and what its inputs look like on :data:`REFERENCE_RECORD`, a simulated grasp
of a rubber object shipped with the package (the estimator's finger only).
:func:`mismatches` measures that record again with today's code and names
every input that moved: a change that alters the inputs without raising the
version fails the shipped models' test, and a change that leaves them alone
costs no retrain.

The summary (:func:`summarise_inputs`) keeps the force and width and the
analytical features whole, and of each image its sum, sum of absolute values
and peak, which a shifted, scaled or resampled depth map changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from estimator.inference.inputs import Variant, encode
from estimator.inference.sampling import sample_grasp
from teleop.record import read_record
from teleop.settings import Settings

__all__ = ["REFERENCE_RECORD", "RTOL", "mismatches", "reference_inputs", "summarise_inputs"]

REFERENCE_RECORD = Path(__file__).resolve().parent.parent / "models" / "reference.grasp"
RTOL = 1e-3  # float32 sums over a few thousand pixels, and a JPEG decoder's rounding
ATOL = 1e-5


def reference_inputs(variant: Variant, *, settings: Settings) -> dict[str, np.ndarray]:
    """The encoded model inputs of ``variant`` on the reference record, measured as the live
    estimator measures (the record's own sensor calibration)."""
    sampled = sample_grasp(read_record(REFERENCE_RECORD), settings=settings, calibration=None,
                           n_frames=variant.n_frames, size_px=variant.size_px, rgb=variant.image == "rgb",
                           markers=variant.markers, window_m=variant.window_m)
    if not sampled:
        raise ValueError(f"{REFERENCE_RECORD}: the reference grasp gives no sample ({sampled.reason})")
    return encode(variant, [sampled], where=str(REFERENCE_RECORD))


def summarise_inputs(batch: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """JSON-ready summary of one grasp's encoded inputs (module notes)."""
    out: dict[str, list[float]] = {}
    for name, array in batch.items():
        array = np.asarray(array, dtype=np.float64)[0]
        if name == "frames":
            flat = array.reshape(array.shape[0], -1)
            out["frames_sum"] = flat.sum(axis=1).tolist()
            out["frames_abs_sum"] = np.abs(flat).sum(axis=1).tolist()
            out["frames_peak"] = np.abs(flat).max(axis=1).tolist()
        else:
            out[name] = array.tolist()
    return out


def mismatches(recorded: dict[str, Any], variant: Variant, *, settings: Settings) -> list[str]:
    """What differs between the ``recorded`` summary and today's inputs on the reference record
    (an empty list when they agree to :data:`RTOL`)."""
    now = summarise_inputs(reference_inputs(variant, settings=settings))
    problems = []
    for name in sorted(set(recorded) | set(now)):
        old, new = recorded.get(name), now.get(name)
        if old is None or new is None or len(old) != len(new):
            problems.append(f"{name}: recorded {old}, now {new}")
        elif not np.allclose(new, old, rtol=RTOL, atol=ATOL):
            problems.append(f"{name}: recorded {np.round(old, 6).tolist()}, now {np.round(new, 6).tolist()}")
    return problems
