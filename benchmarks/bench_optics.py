"""Time the simulated tactile camera: render, camera noise, JPEG, and a whole capture.

Usage::

    .venv/bin/python benchmarks/bench_optics.py [--repeats 300] [--threads 1] [--clock wall|cpu]

Prints the median and 90th percentile (ms) of building a camera (a simulated
grasp builds one per finger) and, per stage, of rendering height maps from no
contact to a contact over the whole pad, on the left (no markers) and right
(markers) sensors of the shipped settings; under each row, its medians in
frame baselines (``bl``, :class:`scriptkit.Baseline`, timed before and after
the stages under the same threads, in wall time). ``--threads 1`` (the default)
pins OpenCV to one thread, so the figures are per core.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import cv2
import numpy as np
from scriptkit import Baseline, run_script

from teleop.clikit import positive_int
from teleop.settings import load_settings
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import sphere_press_height


def scenarios(sensor) -> dict[str, np.ndarray]:
    """Height maps (m) on the grid, from none to the whole pad in contact."""
    rows, cols = sensor.image_shape
    pitch = sensor.pixel_pitch_m
    centre = ((cols - 1) / 2, (rows - 1) / 2)
    texture = cv2.GaussianBlur(np.random.default_rng(0).normal(0, 1, (rows, cols)), (0, 0), 3)
    return {
        "no contact": np.zeros((rows, cols)),
        "2 mm ball, 0.8 mm deep": sphere_press_height((rows, cols), center_px=centre, ball_radius_m=2e-3,
                                                      depth_m=0.8e-3, pixel_pitch_m=pitch),
        "40 mm sphere, 1 mm deep": sphere_press_height((rows, cols), center_px=centre, ball_radius_m=40e-3,
                                                       depth_m=1e-3, pixel_pitch_m=pitch),
        "whole pad, textured": 0.3e-3 + 20e-6 * texture / texture.std(),
    }


def timed(function, repeats: int, clock=time.perf_counter) -> tuple[float, float]:
    function()  # warm up
    samples = []
    for _ in range(repeats):
        start = clock()
        function()
        samples.append(clock() - start)
    return float(np.median(samples) * 1e3), float(np.percentile(samples, 90) * 1e3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=positive_int, default=300, help="timed calls per stage and scenario")
    parser.add_argument("--threads", type=positive_int, default=1, help="OpenCV threads (1: per-core figures)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall: elapsed time; cpu: this thread's CPU time (steadier on a busy "
                             "machine; equals wall time per core when OpenCV runs one thread)")
    parser.add_argument("--json", action="store_true", help="print all figures as one JSON object last")
    return run_script(parser, measure)


def measure(args: argparse.Namespace) -> None:
    clock = time.perf_counter if args.clock == "wall" else time.thread_time
    cv2.setNumThreads(args.threads)
    settings = load_settings()
    baseline = Baseline()
    baseline.time()
    results = []
    for finger in ("left", "right"):
        sensor = settings.sensor(finger)
        camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(0))
        setup = timed(lambda s=sensor: OpticsRenderer(s, sim=settings.simulation,
                                                     rng=np.random.default_rng(1)),
                      max(args.repeats // 10, 5), clock)
        results.append({"sensor": finger, "markers": sensor.markers, "setup_ms": setup})
        for name, height in scenarios(sensor).items():
            frame = camera.render(height)
            noisy = camera.add_noise(frame)
            quality = [cv2.IMWRITE_JPEG_QUALITY, settings.simulation.jpeg_quality]
            results.append({
                "sensor": finger,
                "markers": sensor.markers,
                "height_map": name,
                "contact_fraction": float((height > 0).mean()),
                "render_ms": timed(lambda h=height, c=camera: c.render(h), args.repeats, clock),
                "noise_ms": timed(lambda f=frame, c=camera: c.add_noise(f), args.repeats, clock),
                "jpeg_ms": timed(lambda f=noisy, q=quality: cv2.imencode(".jpg", f, q), args.repeats, clock),
                "capture_ms": timed(lambda h=height, c=camera: c.capture(h), args.repeats, clock),
            })
    baseline.time()
    print(f"{platform.processor() or platform.machine()}, OpenCV {cv2.__version__}, "
          f"{cv2.getNumThreads()} thread(s), {args.repeats} repeats, {args.clock} clock; median / p90 in ms")
    print(baseline.line())
    print(f"{'sensor':<14}{'height map':<26}{'contact':>8}{'render':>14}{'noise':>14}{'jpeg':>14}{'capture':>14}")
    for row in results:
        label = f"{row['sensor']}{' (markers)' if row['markers'] else ''}"
        stages = [k for k in ("setup_ms", "render_ms", "noise_ms", "jpeg_ms", "capture_ms") if k in row]
        row |= {f"{k[:-3]}_median_in_baselines": baseline.ratio(row[k][0]) for k in stages}
        if "setup_ms" in row:
            setup = row["setup_ms"]
            print(f"{label:<14}{'new camera (procedural background)':<48}{setup[0]:>8.2f} /{setup[1]:>4.1f}"
                  f"{row['setup_median_in_baselines']:>8.2f} bl")
            continue
        cells = "".join(f"{row[k][0]:>8.2f} /{row[k][1]:>4.1f}" for k in stages)
        ratios = "".join(f"{row[k[:-3] + '_median_in_baselines']:>11.2f} bl" for k in stages)
        print(f"{label:<14}{row['height_map']:<26}{row['contact_fraction']:>8.0%}{cells}")
        print(f"{'':<48}{ratios}")
    if args.json:
        print(json.dumps({**baseline.figures(), "threads": cv2.getNumThreads(), "repeats": args.repeats,
                          "clock": args.clock, "results": results}))

if __name__ == "__main__":
    raise SystemExit(main())
