"""How every ``teleop calibrate`` command ends: the result written into the settings file it was
given (unless the fit was refused), the JSON report or the changes printed, the exit status."""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from teleop.settings_edit import format_changes, update_settings_file

__all__ = ["conclude", "say"]


def say(text: str) -> None:
    """A line for the person at the rig (stderr, so stdout stays the report)."""
    print(text, file=sys.stderr, flush=True)


def conclude(what: str, settings_path: str | Path, *, report: Mapping[str, Any], changes: Mapping[str, Any],
             refused: str = "", summary: str = "", as_json: bool = False) -> int:
    """Write ``changes`` (dotted keys) into ``settings_path`` unless ``refused`` says why not; print the
    ``report`` with the changes written as one JSON line when ``as_json``; say the refusal or the
    ``summary``; print the changes when not ``as_json``. Returns the exit status: 1 when refused."""
    written = [] if refused or not changes else update_settings_file(Path(settings_path), changes)
    if as_json:
        print(json.dumps({**report, "changes": [dataclasses.asdict(c) for c in written]}))
    if refused:
        say(f"{what} refused: {refused}; {settings_path} not changed")
        return 1
    if summary:
        say(summary)
    if not as_json:
        print(format_changes(written))
    return 0
