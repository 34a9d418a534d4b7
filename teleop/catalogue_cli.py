"""``teleop catalogue``: list an object catalogue (the project's TOML or the published CSV table).

The listing ends with the number of objects and, for a CSV table, of the rows skipped as
unlabelled (no modulus). Sizes: a CSV table's ``Radius [m]`` gives a cylinder as long as it is
wide; a TOML cylinder or hex prism has a round or regular cross-section, ``size_m[0]`` across
(:mod:`teleop.catalogue`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json

from teleop.catalogue import default_catalogue_path, load_catalogue


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "List an object catalogue, and how many rows of a CSV table were skipped as unlabelled (no modulus). "
        "Sizes: a CSV table's 'Radius [m]' gives a sphere's diameter, and a cylinder's diameter and length "
        "alike (d, d, d); give a cylinder's length in a TOML catalogue's size_m = [diameter, diameter, length]. "
        "A cylinder is round and a hex prism regular (size_m = [across flats, across corners, length]): a "
        "size_m[1] that says otherwise is refused.")
    parser.add_argument("path", nargs="?", default=str(default_catalogue_path()),
                        help="catalogue: project .toml or published .csv object table")
    parser.add_argument("--json", action="store_true",
                        help='print one JSON object {"path": ..., "objects": [...], "unlabelled": [labels of skipped rows]} on the last line')


def run(args: argparse.Namespace) -> int:
    unlabelled: list[str] = []
    objects = load_catalogue(args.path, unlabelled=unlabelled)
    if args.json:
        print(json.dumps({"path": str(args.path), "objects": [dataclasses.asdict(o) for o in objects],
                          "unlabelled": unlabelled}))
        return 0
    print(f"{'object':32s} {'shape':10s} {'material':10s} {'E':>13s}")
    for obj in objects:
        print(f"{obj.name:32s} {obj.shape:10s} {obj.material:10s} {obj.modulus_pa:10.3g} Pa")
    skipped = (f"; {len(unlabelled)} row{'' if len(unlabelled) == 1 else 's'} skipped as unlabelled (no modulus: "
               f"{', '.join(unlabelled[:3])}{', ...' if len(unlabelled) > 3 else ''})" if unlabelled else "")
    print(f"{len(objects)} object{'' if len(objects) == 1 else 's'} in {args.path}{skipped}")
    return 0
