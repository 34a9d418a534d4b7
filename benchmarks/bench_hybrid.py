"""Latency and error of the default model against the analytical estimators, per grasp, on one core.

Usage::

    .venv/bin/python benchmarks/bench_hybrid.py RECORDS_DIR [--model DIR] [--calibration CAL]
        [--repeats 5] [--limit K] [--no-width-lag]

Prints the figures of ``estimator bench`` (every configuration's median latency
from decoded frames to E, its error over the labelled records, the Pareto
frontier) for the default model (``estimator/models/default``, or ``--model``),
then the hybrid path split into its stages, each a median over grasps of the
per-grasp median time, over the grasps it can sample:

``segment``
    segmentation, force and width at every frame (``measure_grasp(tactile=False)``);
``reference``
    the no-contact reference: warp and median of the frames before the onset;
``warp``, ``depth``, ``features``
    the sampled loading frames warped and cropped onto the depth grid (binned by the
    settings' ``estimator.depth_binning``, from frames decoded that much smaller), their
    depth reconstructed, their contact features (the parts of ``GraspStream.measurements`` after
    the reference);
``fits``
    the four analytical estimates over the sampled frames;
``encode``, ``network``
    the model inputs batched and reduced, and the network in onnxruntime (one thread);
``sample``
    all of :func:`~estimator.inference.sampling.sample_grasp` (segment to fits) as the hybrid runs it.

The stages are timed on the records ``estimator bench`` benched (readable and labelled); when the
hybrid refuses every one of their grasps there is nothing to time: the script says so, status 2.
Each figure is also given in frame baselines (``bl``, :class:`scriptkit.Baseline`, timed before the
bench and after the stages): the table's p50, and every stage.

BLAS and OpenMP are limited to one thread before numpy loads, and the process
is pinned to one CPU with OpenCV single-threaded.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scriptkit import Baseline, BenchmarkError, run_script  # noqa: E402

from estimator.analytical import METHODS  # noqa: E402
from estimator.evaluation.bench import bench, configurations, one_core, timed  # noqa: E402
from estimator.evaluation.bench_cli import cell  # noqa: E402
from estimator.features import contact_features  # noqa: E402
from estimator.inference.hybrid import HybridEstimator  # noqa: E402
from estimator.inference.infer import CompliancePredictor, default_model_dir  # noqa: E402
from estimator.inference.inputs import encode  # noqa: E402
from estimator.inference.sampling import calibration_for, decoded  # noqa: E402
from estimator.measure import estimate_grasp, measure_grasp, no_contact_reference  # noqa: E402
from estimator.perception.depth import reconstruct_depth  # noqa: E402
from estimator.perception.grid import grid_calibration, to_grid  # noqa: E402
from estimator.perception.markers import detect_markers  # noqa: E402
from estimator.settings import estimator_settings  # noqa: E402
from teleop.clikit import positive_int  # noqa: E402
from teleop.record import find_records, read_record  # noqa: E402
from teleop.settings import load_settings  # noqa: E402

STAGES = ("segment", "reference", "warp", "depth", "features", "fits", "encode", "network", "sample")


def stage_runs(record, sampled, *, settings, predictor, calibration):
    """One grasp's hybrid stages (module notes) as functions of nothing, on the sampled grasp's own inputs."""
    variant, finger = predictor.variant, settings.sensing.finger
    sampling = settings.with_section(replace(estimator_settings(settings), n_frames=variant.n_frames))
    m = sampled.measurements
    binning, sensor, grid, reference = m.depth_binning, m.sensor, m.grid, m.reference_bgr
    cal = grid_calibration(calibration_for(record.sensor(finger), calibration), binning)
    positions = np.searchsorted(m.segment.frame_t_s, m.t_s)  # the sampled loading frames
    raw = [record.stream(finger).frame(int(i), reduce=binning) for i in m.segment.frame_index[positions] + m.frames_dropped]
    batch = encode(variant, [sampled])

    def depth():
        return [reconstruct_depth(image, reference, cal,
                                  marker_mask=detect_markers(image, reference) if grid.markers else None)
                for image in m.image_bgr]

    return {
        "segment": lambda: measure_grasp(record, settings=sampling, tactile=False),
        "reference": lambda: no_contact_reference(record, finger, m.segment, binning=binning),
        "warp": lambda: [to_grid(frame, sensor, binning=binning) for frame in raw],
        "depth": depth,
        "features": lambda: contact_features(m.depth_m, pixel_pitch_m=grid.pixel_pitch_m,
                                             contact_threshold_m=grid.contact_threshold_m),
        "fits": lambda: [estimate_grasp(m, method, settings=settings) for method in METHODS],
        "encode": lambda: encode(variant, [sampled]),
        "network": lambda: predictor.predict_logits(batch),
    }


def stages(paths, *, settings, predictor, calibration, repeats):
    """Median per-grasp times (ms) of the hybrid's stages (module notes) over the records it can sample.

    Raises BenchmarkError when it can sample none (every grasp refused): there is nothing to time."""
    hybrid = HybridEstimator(predictor, settings=settings, calibration=calibration)
    times = {name: [] for name in STAGES}
    with one_core():
        for path in paths:
            record = decoded(read_record(path), reduce=estimator_settings(settings).depth_binning)
            sampled, sample_ms = timed(hybrid.sample, record, repeats)
            if not sampled:
                continue
            runs = stage_runs(record, sampled, settings=settings, predictor=predictor, calibration=calibration)
            for name, run in runs.items():
                times[name].append(timed(lambda _, run=run: run(), record, repeats)[1])
            times["sample"].append(sample_ms)
    if not times["sample"]:
        folder = os.path.commonpath([Path(p).parent for p in paths]) if paths else "no records"
        raise BenchmarkError(f"{folder}: the hybrid refused every grasp benched ({len(paths)} of {len(paths)}: "
                             "too little data to sample): no stage to time")
    return {"grasps": len(times["sample"]), **{name: float(np.median(t)) for name, t in times.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("records", type=Path, help="directory of labelled .grasp records")
    parser.add_argument("--model", type=Path, default=default_model_dir(), help="model directory")
    parser.add_argument("--calibration", default=None, help="calibration for every record (default: the sensor's)")
    parser.add_argument("--repeats", type=positive_int, default=5, help="timed runs per grasp and configuration")
    parser.add_argument("--limit", type=positive_int, default=None, help="only the first K records")
    parser.add_argument("--no-width-lag", dest="width_lag", action="store_false",
                        help="as estimator bench --no-width-lag: the analytical methods take the widths' times "
                             "as stamped")
    return run_script(parser, measure)


def measure(args: argparse.Namespace) -> None:
    settings = load_settings()
    paths = find_records(args.records)[: args.limit]
    predictor = CompliancePredictor(args.model, threads=1)
    configs = configurations(settings=settings, calibration=args.calibration,
                             frames=[predictor.variant.n_frames], models=[predictor],
                             correct_width_lag=args.width_lag)
    baseline = Baseline()
    with one_core():  # as the bench and the stages run
        baseline.time()
    result = bench(paths, settings=settings, configs=configs, calibration=args.calibration, repeats=args.repeats)
    skipped = {entry["path"] for entry in result["skipped_records"]}  # unreadable or unlabelled: not benched
    parts = stages([p for p in paths if str(p) not in skipped], settings=settings, predictor=predictor,
                   calibration=args.calibration, repeats=args.repeats)
    with one_core():
        baseline.time()
    print(f"{platform.processor() or platform.machine()}, {result['labelled']} labelled grasps, "
          f"{args.repeats} timed runs each, pinned to one core: {result['one_core']}")
    print(baseline.line())
    print(f"{'configuration':<44} {'p50 ms':>8} {'p50 bl':>7} {'p90 ms':>8} {'felt err':>8} {'felt2x':>6} "
          f"{'log10 err':>9} {'within10x':>9} {'refused':>7}  pareto")
    for c in sorted(result["configs"], key=lambda c: c["latency_ms_p50"]):
        cells = [cell(c["felt_log10_error"], ".3f", 8), cell(c["felt_within_2x"], ".0%", 6),
                 cell(c["log10_error"], ".2f", 9), cell(c["within_10x"], ".0%", 9)]
        print(f"{c['name']:<44} {c['latency_ms_p50']:>8.2f} {baseline.ratio(c['latency_ms_p50']):>7.2f} "
              f"{c['latency_ms_p90']:>8.2f} {' '.join(cells)} {c['refusals']:>7}  {'*' if c['pareto'] else ''}")
    print(f"hybrid stages over {parts['grasps']} grasps (median ms per grasp, and bl): "
          + ", ".join(f"{name} {parts[name]:.2f} ({baseline.ratio(parts[name]):.2f})" for name in STAGES))


if __name__ == "__main__":
    raise SystemExit(main())
