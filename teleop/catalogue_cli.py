"""``teleop catalogue``: list an object catalogue (the project's TOML or the published CSV table)."""

from __future__ import annotations

import argparse
import dataclasses
import json

from teleop.catalogue import default_catalogue_path, load_catalogue


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", nargs="?", default=str(default_catalogue_path()),
                        help="catalogue: project .toml or published .csv object table")
    parser.add_argument("--json", action="store_true",
                        help='print one JSON object {"path": ..., "objects": [...]} on the last line')


def run(args: argparse.Namespace) -> int:
    objects = load_catalogue(args.path)
    if args.json:
        print(json.dumps({"path": str(args.path), "objects": [dataclasses.asdict(o) for o in objects]}))
        return 0
    print(f"{'object':32s} {'shape':10s} {'material':10s} {'E':>13s}")
    for obj in objects:
        print(f"{obj.name:32s} {obj.shape:10s} {obj.material:10s} {obj.modulus_pa:10.3g} Pa")
    print(f"{len(objects)} object{'' if len(objects) == 1 else 's'} in {args.path}")
    return 0
