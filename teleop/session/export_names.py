"""Names of exported records, and the records of a grasp already in an export folder.

A record is named ``<log stem>_<session id>_<grasp id>.grasp`` (``-2``, ``-3``, ... after a grasp id
the session used before). The log's file name is in it so that two sessions exported into one folder
never share a name; but one session can be exported from two logs (a log cut short and the log
``teleop recover`` made of it, or a copy under another name), and then the same grasp would be in
the folder twice, under two names, and count twice in a dataset. :func:`same_grasp_records` finds
those: the records in the folder whose name ends in the same ``_<session id>_<grasp id>.grasp`` and
whose provenance names the same session id and grasp id.

A log stem too long for the name to fit a file system's 255-byte limit is cut, and a short hash of
the whole stem put after it, so that the name stays within the limit and apart from other logs'.
A grasp id (up to 256 characters on the wire) or session id longer than :data:`_ID_MAX_BYTES` is cut
the same way: its start, ``-`` and a short hash of the whole id. The limit counts the hidden name
``.<name>.exporting`` the export writes first, which is 11 bytes longer.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

from teleop.record import safe_name

__all__ = ["record_name", "same_grasp_records"]


# A file name's limit in bytes (ext4, XFS, btrfs, APFS; NTFS's 255 UTF-16 units are no fewer), less
# the 11 bytes the export's hidden name ``.<name>.exporting`` adds while the record is written.
_NAME_MAX_BYTES = 255 - len("..exporting")
# The most bytes a grasp id or session id takes in a name; a longer one is cut and hashed.
_ID_MAX_BYTES = 80
# Room kept after the grasp id for "-<k>" and the suffix, so every k shares one cut stem.
_SUFFIX_ROOM = len("-999.grasp")
_HASH_CHARS = 10


def _cut(text: str, safe: str, room: int) -> str:
    """``safe`` (the file-name form of ``text``) cut to ``room`` bytes with ``-`` and a hash of
    ``text`` at its end (surrogateescape: a Linux file name need not be UTF-8)."""
    digest = hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()[:_HASH_CHARS]
    keep = max(room - len(digest) - 1, 0)
    cut = safe.encode()[:keep].decode("utf-8", "ignore")  # cut in bytes, never inside a character
    return f"{cut}-{digest}" if cut else digest


def _id_part(value: str) -> str:
    """:func:`safe_name` of a grasp id or session id, or when longer than :data:`_ID_MAX_BYTES`
    its start and ``-`` and a hash of the whole id."""
    safe = safe_name(value)
    return safe if len(safe.encode()) <= _ID_MAX_BYTES else _cut(value, safe, _ID_MAX_BYTES)


def _log_part(log_path: Path, session: str, grasp_id: str) -> str:
    """The log stem as the start of a record's name: :func:`safe_name` of it, or when that would
    push the name past :data:`_NAME_MAX_BYTES`, its start and ``-`` and a hash of the whole stem."""
    stem = safe_name(log_path.stem)
    tail = f"_{_id_part(session)}_{_id_part(grasp_id)}"
    room = _NAME_MAX_BYTES - _SUFFIX_ROOM - len(tail.encode())
    if len(stem.encode()) <= room:
        return stem
    # The hash keeps apart logs whose long stems differ only past the cut.
    return _cut(log_path.stem, stem, room)


def record_name(log_path: Path, session: str, grasp_id: str, taken: set[str]) -> str:
    """``<log stem>_<session id>_<grasp id>.grasp``; ``-2``, ``-3``, ... after a grasp id the
    session used before (a grasp id started again after it ended). A stem too long for the name
    to fit in 255 bytes is cut and a hash of it added (:func:`_log_part`), and so is a grasp id or
    session id longer than :data:`_ID_MAX_BYTES` (:func:`_id_part`)."""
    base = f"{_log_part(log_path, session, grasp_id)}_{_id_part(session)}_{_id_part(grasp_id)}"
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
    key = name[len(_log_part(log_path, session, grasp_id)):]  # "_<session id>_<grasp id>[-k].grasp"
    found = []
    for path in records:
        if path.name == name or not path.name.endswith(key) or not path.is_file():
            continue
        extra = _provenance(path)
        if extra.get("session_id") == session and extra.get("grasp_id") == grasp_id:
            found.append((path, str(extra.get("session", "an unknown log"))))
    return found
