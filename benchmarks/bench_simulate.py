"""Grasps per second per core of the grasp simulator, every frame of every grasp rendered.

Usage::

    .venv/bin/python benchmarks/bench_simulate.py [--grasps 3] [--json]

Simulates ``--grasps`` grasps of each of a few objects spanning the materials
(foam to steel) with the shipped settings, in this one process with OpenCV on
one thread, and prints per object the median CPU seconds per grasp (process
time: the figure per core even when other work shares the machine; wall time
beside it), the frames rendered per grasp (both fingers, all of the record:
approach, loading, hold, release) and the median CPU time of the contact
mechanics alone; then the median over objects of grasps per second per core.
Each CPU time is also given in frame baselines (``bl``, :class:`scriptkit.Baseline`,
timed before and after the grasps on the same one thread, in wall time: alike for
one thread on an idle core). Medians
only: a few grasps per object give no meaningful tail. Nothing is written to disk.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import cv2
import numpy as np
from scriptkit import Baseline, run_script

from teleop.catalogue import ObjectSpec
from teleop.clikit import positive_int
from teleop.settings import load_settings
from teleop.sim.grasp import load_curve, simulate_grasp

OBJECTS = (
    ObjectSpec(name="bench_foam_block", shape="box", material="foam", modulus_pa=5.0e3),
    ObjectSpec(name="bench_rubber_ball", shape="sphere", material="rubber", modulus_pa=6.0e5),
    ObjectSpec(name="bench_plastic_cylinder", shape="cylinder", material="plastic", modulus_pa=2.5e9),
    ObjectSpec(name="bench_wood_irregular", shape="irregular", material="wood", modulus_pa=1.0e10),
    ObjectSpec(name="bench_steel_nut", shape="hex_prism", material="metal", modulus_pa=2.0e11),
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grasps", type=positive_int, default=3, help="timed grasps per object (after one warm-up grasp)")
    parser.add_argument("--json", action="store_true", help="print all figures as one JSON object last")
    return run_script(parser, measure)


def measure(args: argparse.Namespace) -> None:
    cv2.setNumThreads(1)
    settings = load_settings()
    sensors = {s.finger: s for s in settings.sensors}
    simulate_grasp(OBJECTS[0], settings=settings, rng=np.random.default_rng(0))  # warm caches and imports
    baseline = Baseline()
    baseline.time()
    rows = []
    for obj in OBJECTS:
        seconds, wall, mechanics, frames = [], [], [], []
        for seed in range(1, args.grasps + 1):
            start, start_wall = time.process_time(), time.perf_counter()
            record, truth = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(seed))
            seconds.append(time.process_time() - start)
            wall.append(time.perf_counter() - start_wall)
            frames.append(sum(len(s) for s in record.frames))
            start = time.process_time()
            load_curve(obj, truth.scene, sensors=sensors, grid_px=settings.simulation.grid_px,
                       max_force_n=truth.target_force_n, finger_stiffness_n_per_m=truth.finger_stiffness_n_per_m,
                       size=truth.size_m)
            mechanics.append(time.process_time() - start)
        rows.append({
            "object": obj.name, "material": obj.material,
            "cpu_s_per_grasp": float(np.median(seconds)), "wall_s_per_grasp": float(np.median(wall)),
            "frames_per_grasp": float(np.median(frames)), "mechanics_cpu_s": float(np.median(mechanics)),
            "grasps_per_s": 1.0 / float(np.median(seconds)),
        })
    baseline.time()
    print(baseline.line())
    for r in rows:
        r["cpu_per_grasp_in_baselines"] = baseline.ratio(r["cpu_s_per_grasp"] * 1e3)
        r["mechanics_cpu_in_baselines"] = baseline.ratio(r["mechanics_cpu_s"] * 1e3)
        print(f"{r['object']:24s} {r['material']:8s} {r['cpu_s_per_grasp']:6.3f} s/grasp "
              f"({r['cpu_per_grasp_in_baselines']:5.0f} bl; wall {r['wall_s_per_grasp']:6.3f})"
              f"  {r['frames_per_grasp']:4.0f} frames  mechanics {r['mechanics_cpu_s']:6.3f} s "
              f"({r['mechanics_cpu_in_baselines']:4.0f} bl)  -> {r['grasps_per_s']:5.2f} grasps/s")
    overall = float(np.median([r["grasps_per_s"] for r in rows]))
    per_grasp = baseline.ratio(1e3 / overall)
    print(f"median over objects: {overall:.2f} grasps/s/core, one grasp per {per_grasp:.0f} bl "
          f"({platform.processor() or platform.machine()}, {args.grasps} grasps per object)")
    if args.json:
        print(json.dumps({**baseline.figures(), "grasps_per_s_per_core": overall,
                          "baselines_per_grasp": per_grasp, "objects": rows}))


if __name__ == "__main__":
    raise SystemExit(main())
