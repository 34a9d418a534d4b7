"""Time depth reconstruction of one 250x350 tactile frame on one core.

Usage::

    .venv/bin/python benchmarks/bench_depth.py [--repeats 500]

The frame is real: the centre 250x350 window of taxim's GelSight presses
(2 mm ball, 0.0295 mm/px); a calibration is fitted on every other press whose
contact lies inside the window, and a held-out press is reconstructed. Threads
are pinned to one (OpenMP, MKL, OpenBLAS, OpenCV; scipy.fft runs with
``workers=1``). Prints the median and 90th percentile (ms) of the whole
``reconstruct_depth`` and of its stages (gradient lookup, Poisson solve), and
of the marker path for reference: the same frame and reference with dark dots
drawn on a 16 px grid, as the simulated marker gel (the reference's dots 3 px
away from the frame's), their
detection, and reconstruction with them masked and inpainted; each median also
in frame baselines (``bl``, :class:`scriptkit.Baseline`, timed before and after
the stages on the same one thread). Target: the whole reconstruction (no
markers) in 2 ms or less.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scriptkit import Baseline, run_script  # noqa: E402

from estimator.perception import (  # noqa: E402
    detect_markers,
    fit_calibration,
    fit_sphere,
    load_presses,
    poisson_depth,
    reconstruct_depth,
)
from teleop.clikit import positive_int  # noqa: E402

WINDOW = (slice(115, 365), slice(145, 495))  # rows, cols: 250 x 350 around the image centre
PITCH_M, BALL_M = 0.0295e-3, 2.0e-3


def with_dots(image: np.ndarray, offset: tuple[int, int]) -> np.ndarray:
    """``image`` with dark marker dots (radius 3 px) on a 16 px grid shifted by ``offset``."""
    dots = np.zeros(image.shape[:2], np.uint8)
    for y in range(8 + offset[1], image.shape[0], 16):
        for x in range(8 + offset[0], image.shape[1], 16):
            cv2.circle(dots, (x, y), 3, 1, -1)
    out = image.copy()
    out[dots.astype(bool)] //= 3
    return out


def timed(fn, repeats: int) -> np.ndarray:
    """Wall times (ms) of ``repeats`` calls after a few warm-up calls."""
    for _ in range(5):
        fn()
    times = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - start
    return times * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=positive_int, default=500, help="timed calls per stage")
    return run_script(parser, measure)


def measure(args: argparse.Namespace) -> None:
    cv2.setNumThreads(1)

    spec = importlib.util.find_spec("taxim")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("taxim is not installed: its real presses are the benchmark frames")
    presses = load_presses(Path(next(iter(spec.submodule_search_locations))) / "calib/gelsight/dataPack.npz")
    rows, cols = WINDOW
    centers = presses.centers_px - [cols.start, rows.start]
    inside = np.flatnonzero(
        (centers[:, 0] - presses.radii_px > 5) & (centers[:, 0] + presses.radii_px < cols.stop - cols.start - 5)
        & (centers[:, 1] - presses.radii_px > 5) & (centers[:, 1] + presses.radii_px < rows.stop - rows.start - 5)
    )
    train, held_out = inside[::2], inside[1::2]
    reference = np.ascontiguousarray(presses.reference[WINDOW])
    images = np.ascontiguousarray(presses.images[:, rows, cols])
    calibration = fit_calibration(reference, images[train], centers[train], presses.radii_px[train],
                                  ball_radius_m=BALL_M, pixel_pitch_m=PITCH_M)
    frame = images[held_out[0]]
    gx, gy = calibration.gradients(frame, reference)
    marked_frame, marked_reference = with_dots(frame, (0, 0)), with_dots(reference, (3, 0))
    marker_mask = detect_markers(marked_frame, marked_reference)
    sphere = fit_sphere(reconstruct_depth(frame, reference, calibration), pixel_pitch_m=PITCH_M)

    stages = {
        "reconstruct_depth (whole)": lambda: reconstruct_depth(frame, reference, calibration),
        "  gradient lookup": lambda: calibration.gradients(frame, reference),
        "  Poisson solve (DST-II)": lambda: poisson_depth(gx, gy, pixel_pitch_m=PITCH_M),
        "detect_markers (dotted frame)": lambda: detect_markers(marked_frame, marked_reference),
        "reconstruct_depth with marker_mask": lambda: reconstruct_depth(
            marked_frame, marked_reference, calibration, marker_mask=marker_mask),
    }
    print(f"frame {frame.shape[0]}x{frame.shape[1]} (press {held_out[0]}, calibrated on {len(train)} presses; "
          f"fitted sphere {sphere.radius_m * 1e3:.3f} mm), {args.repeats} repeats, one thread, "
          f"{platform.processor() or platform.machine()}; marker mask covers {marker_mask.mean():.1%}")
    baseline = Baseline()
    baseline.time()
    times = {name: timed(fn, args.repeats) for name, fn in stages.items()}
    baseline.time()
    print(baseline.line())
    results = {}
    for name, t in times.items():
        median = float(np.median(t))
        results[name.strip()] = {"median_ms": median, "p90_ms": float(np.percentile(t, 90)),
                                 "median_in_baselines": baseline.ratio(median)}
        print(f"{name:38s} median {median:7.3f} ms ({baseline.ratio(median):5.2f} bl)   "
              f"p90 {np.percentile(t, 90):7.3f} ms")
    print(json.dumps({**baseline.figures(), **results}))


if __name__ == "__main__":
    raise SystemExit(main())
