"""What the scripts here share with the ``teleop``, ``estimator`` and ``haptics`` commands: bad options
refused by argparse with what was expected, and the project's own errors (every one a
:class:`~teleop.errors.ComplianceTeleopError`) printed as one line with exit status 2, never a
traceback or figures of nothing.

A script imports it by name (``python benchmarks/NAME.py`` puts this folder first on ``sys.path``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from teleop.errors import ComplianceTeleopError


def run_script(parser: argparse.ArgumentParser, work: Callable[[argparse.Namespace], int | None]) -> int:
    """Parse the command line and run ``work`` on it; its exit status."""
    args = parser.parse_args()
    try:
        return int(work(args) or 0)
    except ComplianceTeleopError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
