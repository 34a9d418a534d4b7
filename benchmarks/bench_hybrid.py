"""Latency and error of the default model against the analytical estimators, per grasp, on one core.

Usage::

    .venv/bin/python benchmarks/bench_hybrid.py RECORDS_DIR [--model DIR] [--calibration CAL]
        [--repeats 5] [--limit K]

Prints the figures of ``estimator bench`` (every configuration's median latency
from decoded frames to E, its error over the labelled records, the Pareto
frontier) for the default model (``estimator/models/default``, or ``--model``),
then the hybrid path split into its stages, each a median over grasps of the
per-grasp median: the no-contact reference, the N-frame measurement with the
analytical fits (:func:`~estimator.learned.inputs.sample_grasp`), and the
network alone in onnxruntime (one thread). BLAS and OpenMP are limited to one
thread before numpy loads, and ``estimator bench`` pins the process to one CPU.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from estimator.bench import bench, configurations, one_core, timed  # noqa: E402
from estimator.learned.hybrid import HybridEstimator  # noqa: E402
from estimator.learned.infer import CompliancePredictor, default_model_dir  # noqa: E402
from estimator.learned.inputs import decoded, encode  # noqa: E402
from teleop.record import read_record  # noqa: E402
from teleop.settings import load_settings  # noqa: E402


def stages(paths, *, settings, predictor, calibration, repeats):
    """Median per-grasp times (ms) of the hybrid's stages over the records that can be sampled."""
    hybrid = HybridEstimator(predictor, settings=settings, calibration=calibration)
    measure_ms, network_ms = [], []
    with one_core():
        for path in paths:
            record = decoded(read_record(path))
            sampled, ms = timed(hybrid.sample, record, repeats)
            if not sampled:
                continue
            measure_ms.append(ms)
            batch = encode(predictor.variant, [sampled])
            network_ms.append(timed(lambda _, b=batch: predictor.predict_normalised(b), record, repeats)[1])
    return {"grasps": len(measure_ms), "sample_and_fits_ms_p50": float(np.median(measure_ms)),
            "network_ms_p50": float(np.median(network_ms))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("records", type=Path, help="directory of labelled .grasp records")
    parser.add_argument("--model", type=Path, default=default_model_dir(), help="model directory")
    parser.add_argument("--calibration", default=None, help="calibration for every record (default: the sensor's)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per grasp and configuration")
    parser.add_argument("--limit", type=int, default=None, help="only the first K records")
    args = parser.parse_args()
    settings = load_settings()
    paths = sorted(args.records.rglob("*.grasp"))[: args.limit]
    predictor = CompliancePredictor(args.model, threads=1)
    configs = configurations(settings=settings, calibration=args.calibration,
                             frames=[predictor.variant.n_frames], models=[predictor])
    result = bench(paths, settings=settings, configs=configs, repeats=args.repeats)
    print(f"{platform.processor() or platform.machine()}, {result['labelled']} labelled grasps, "
          f"{args.repeats} timed runs each, pinned to one core: {result['one_core']}")
    print(f"{'configuration':<44} {'p50 ms':>8} {'p90 ms':>8} {'log10 err':>9} {'within10x':>9}  pareto")
    for c in sorted(result["configs"], key=lambda c: c["latency_ms_p50"]):
        err = "-" if c["log10_error"] is None else f"{c['log10_error']:.2f}"
        within = "-" if c["within_10x"] is None else f"{c['within_10x']:.0%}"
        print(f"{c['name']:<44} {c['latency_ms_p50']:>8.2f} {c['latency_ms_p90']:>8.2f} {err:>9} {within:>9}  "
              f"{'*' if c['pareto'] else ''}")
    parts = stages(paths, settings=settings, predictor=predictor, calibration=args.calibration,
                   repeats=args.repeats)
    print(f"hybrid stages over {parts['grasps']} grasps (median ms): no-contact reference "
          f"{result['reference_ms_p50']:.2f} (inside the next), sample + fits {parts['sample_and_fits_ms_p50']:.2f}, "
          f"network {parts['network_ms_p50']:.3f}")


if __name__ == "__main__":
    main()
