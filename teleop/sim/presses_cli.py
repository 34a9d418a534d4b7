"""``teleop simulate-presses``: render rigid-ball presses on a simulated sensor (:mod:`teleop.sim.presses`)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from teleop.clikit import non_negative_int, output_file
from teleop.errors import TeleopError
from teleop.settings import default_settings_path, load_settings
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import simulate_presses, write_presses


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, default=argparse.SUPPRESS,
                        help="output .npz file (taxim dataPack layout)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing --out (else it is refused: presses a calibration was fitted "
                             "from would be lost)")
    parser.add_argument("--settings", default=str(default_settings_path()), help="settings TOML file")
    parser.add_argument("--finger", default="left", help="which finger's sensor to simulate")
    parser.add_argument("--n", type=int, default=48, help="number of presses")
    parser.add_argument("--ball-radius-mm", type=float, default=2.0, help="radius of the rigid ball (mm)")
    parser.add_argument("--depth-mm", type=float, nargs=2, default=(0.3, 1.0), metavar=("LO", "HI"),
                        help="press depths are drawn uniformly from LO..HI, in mm (default: 0.3 1.0)")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="random seed (camera noise, background dust, press centres and depths)")
    parser.add_argument("--json", action="store_true", help="print one JSON summary as the last line")


def run(args: argparse.Namespace) -> int:
    out = output_file("--out", args.out, suffixes=(".npz",))  # before the rendering, not after it
    if out.exists() and not args.overwrite:
        raise TeleopError(f"--out {out}: exists already: pass --overwrite to replace it, or another --out")
    settings = load_settings(args.settings)
    sensor = settings.sensor(args.finger)
    camera_rng, press_rng = np.random.default_rng(args.seed).spawn(2)
    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=camera_rng)
    pack = simulate_presses(
        camera, n=args.n, ball_radius_m=args.ball_radius_mm * 1e-3,
        depth_range_m=(args.depth_mm[0] * 1e-3, args.depth_mm[1] * 1e-3), rng=press_rng, progress=True,
    )
    path = write_presses(out, pack)
    summary = {
        "out": str(path),
        "finger": sensor.finger,
        "n": int(args.n),
        "ball_radius_mm": float(args.ball_radius_mm),
        "mm_per_px": float(pack["mm_per_px"]),
        "touch_radius_px": [int(pack["touch_radius"].min()), int(pack["touch_radius"].max())],
        "frame": "warped_cropped",
        "seed": int(args.seed),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {args.n} presses of a {args.ball_radius_mm:g} mm ball on the {sensor.finger} "
              f"sensor to {path} (centres in warped-and-cropped px, {summary['mm_per_px']:.4f} mm/px)")
    return 0
