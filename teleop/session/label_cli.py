"""``teleop label``: attach labels (what each grasp held, and its modulus) to a session log from a CSV."""

from __future__ import annotations

import argparse
import json
import sys

from teleop.bus.messages import LabelBody
from teleop.session.label import label_session

EPILOG = """\
The CSV has a header row and one row per grasp:

  grasp_id,object,modulus_pa,shore_a,shore_00,source,detail
  op-1201-101512-001,stress_ball,,,,,
  op-1201-101512-002,blue gel pad,,,60,,
  op-1201-101512-003,cork mat,1.2e7,,,datasheet,maker's sheet 2024

grasp_id and object are required; the rest may be left out or empty. An object in the catalogue
needs nothing else (source catalogue); otherwise give modulus_pa (Pa; source datasheet, or
measured) or one Shore reading, shore_a (10-90) or shore_00 (45-90), converted to E by Gent's
relation, a 00 reading through the makers' A/00 table first (source durometer; teleop/labels.py
documents the model, its source and its limits).

The labels are written into the log as `label` messages, each just after its grasp; the log is
rewritten next to itself with every original record kept and then moved over the original. A grasp
labelled again takes the newer label. `teleop export` reads them. A log cut short, or with a record
that cannot be read, is refused and left as it is (the error says to `teleop recover` it first); an
attachment whose checksum fails is copied as stored, so the labelled log still says it is damaged.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("log", metavar="LOG", help="session log (.mcap) written by `teleop record`; rewritten in place")
    parser.add_argument("--csv", required=True, metavar="FILE", help="the labels: a CSV with grasp_id, object, ...")
    parser.add_argument(
        "--catalogue",
        metavar="PATH",
        default=None,
        help="object catalogue (.toml or .csv) for objects given without a modulus, and for the material "
        "and shape of every labelled object; attached to the log unless it holds it already "
        "(default: the catalogue attached to the log, else the shipped configs/objects.toml)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (log, csv, labels: [{grasp_id, object_name, modulus_pa, source, detail}], "
        "relabelled: [grasp ids], unended: [labelled grasp ids without an end event, which export skips], "
        "messages, grasps) as the last stdout line",
    )


def run(args: argparse.Namespace) -> int:
    report = label_session(args.log, args.csv, catalogue=args.catalogue)
    print(
        f"labelled {len(report.labels)} grasp(s) of {report.grasps} in {args.log}"
        + (f"; replaced the labels of {', '.join(report.relabelled)}" if report.relabelled else ""),
        file=sys.stderr,
    )
    for label in (LabelBody(**body) for body in report.labels):
        modulus = "the catalogue's" if label.modulus_pa is None else f"{label.modulus_pa:.4g} Pa"
        print(f"  {label.grasp_id}: {label.object_name}, E {modulus} ({label.source})", file=sys.stderr)
    for grasp_id in report.unended:
        print(f"warning: grasp {grasp_id} has no end event in {args.log}: `teleop export` skips it, "
              "so its label is not used", file=sys.stderr)
    if args.json:
        print(json.dumps(report.as_dict()))
    return 0
