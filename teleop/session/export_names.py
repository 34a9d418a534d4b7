"""Names of exported records, and the records of a grasp already in an export folder.

A record is named ``<log stem>_<session id>_<grasp id>.grasp`` (``-2``, ``-3``, ... after a grasp id
the session used before). The log's file name is in it so that two sessions exported into one folder
never share a name; but one session can be exported from two logs (a log cut short and the log
``teleop recover`` made of it, or a copy under another name), and then the same grasp would be in
the folder twice, under two names, and count twice in a dataset. :func:`same_grasp_records` finds
those: the records in the folder whose name ends in the same ``_<session id>_<grasp id>.grasp`` and
whose provenance names the same session id and grasp id.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from teleop.record import safe_name

__all__ = ["record_name", "same_grasp_records"]


def record_name(log_path: Path, session: str, grasp_id: str, taken: set[str]) -> str:
    """``<log stem>_<session id>_<grasp id>.grasp``; ``-2``, ``-3``, ... after a grasp id the
    session used before (a grasp id started again after it ended)."""
    base = f"{safe_name(log_path.stem)}_{safe_name(session)}_{safe_name(grasp_id)}"
    name, k = f"{base}.grasp", 1
    while name in taken:
        k += 1
        name = f"{base}-{k}.grasp"
    taken.add(name)
    return name


def _provenance(path: Path) -> dict:
    """The ``provenance.extra`` of the record at ``path`` (only its header is read); {} when it is
    not a readable record (build-dataset names those itself)."""
    try:
        with zipfile.ZipFile(path) as zf:
            header = json.loads(zf.read("record.json").decode("utf-8"))
        extra = header["provenance"]["extra"]
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile):
        return {}
    return extra if isinstance(extra, dict) else {}


def same_grasp_records(records: list[Path], log_path: Path, name: str, session: str,
                       grasp_id: str) -> list[tuple[Path, str]]:
    """Of ``records`` (the export folder's, listed once per export), those other than ``name`` that hold
    the same grasp of the same session (``name`` as :func:`record_name` gave it for ``log_path``), each
    with the log it came from."""
    key = name[len(safe_name(log_path.stem)):]  # "_<session id>_<grasp id>[-k].grasp"
    found = []
    for path in records:
        if path.name == name or not path.name.endswith(key) or not path.is_file():
            continue
        extra = _provenance(path)
        if extra.get("session_id") == session and extra.get("grasp_id") == grasp_id:
            found.append((path, str(extra.get("session", "an unknown log"))))
    return found
