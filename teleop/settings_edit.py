"""Write calibrated values into a settings TOML file, keeping its comments and layout.

The calibration commands (``teleop calibrate ...``) end by writing what they measured into
the settings file they were given. :func:`update_settings_file` changes only the keys it is
given (``tomlkit`` keeps every comment, blank line and key order of the rest), checks the
whole result before anything is written (the base's tables with
:func:`~teleop.settings.settings_from_mapping`, every package's table by its owner, as
``teleop settings`` does), and replaces the file atomically (a temporary file in the same
folder, then ``os.replace``; a symlink's target, the link kept): a crash or a refused value
leaves the old file as it was.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit.exceptions import TOMLKitError

from teleop.errors import SettingsError
from teleop.settings import package_sections, settings_from_mapping

__all__ = ["SettingChange", "check_writable", "format_changes", "update_settings_file"]


@dataclass(frozen=True)
class SettingChange:
    """One key written: its dotted TOML path, the value it had (None: unset) and the new one."""

    key: str
    old: Any
    new: Any


def _plain(value: Any) -> Any:
    """TOML-ready form of a value: tuples become lists (nested too), numpy values Python ones."""
    if hasattr(value, "tolist"):  # a numpy scalar or array
        value = value.tolist()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def _parent_table(document: tomlkit.TOMLDocument, key: str) -> tuple[Any, str]:
    """The table holding ``key``'s last part (tables on the way created), and that part."""
    parts = key.split(".")
    if not all(p.strip() for p in parts) or len(parts) < 2:
        raise SettingsError(f"settings key {key!r}: expected a dotted path such as 'load_cell.counts_per_n'")
    table: Any = document
    for depth, part in enumerate(parts[:-1]):
        if part not in table:
            table[part] = tomlkit.table()
        table = table[part]
        if not isinstance(table, Mapping):
            raise SettingsError(f"settings key {key!r}: {'.'.join(parts[:depth + 1])} is a value, not a table")
    return table, parts[-1]


def update_settings_file(path: Path, changes: Mapping[str, Any]) -> list[SettingChange]:
    """Write ``changes`` (dotted TOML key -> value) into the settings file at ``path``.

    Parameters
    ----------
    path : Path
        A settings TOML file (:func:`~teleop.settings.load_settings`'s format).
    changes : Mapping
        ``{"load_cell.counts_per_n": 41873.2, "sensors.left.warp_corners_px": [[x, y], ...]}``;
        tables that are missing are created; tuples are written as arrays.

    Returns
    -------
    list of SettingChange
        One per key, in the order given, with the value the file had (None when unset).

    Raises
    ------
    SettingsError
        The file cannot be read or is not TOML, a key is not a dotted path, the file with
        the changes would not be valid settings (the message is the settings check's, with the
        keys changed), or it cannot be written (:func:`check_writable`; the message lists the
        values not written); the file is then left untouched.
    """
    path = Path(path)
    try:
        # as written: CRLF line ends stay CRLF (tomlkit keeps them), a byte-order mark is kept aside
        with open(path, encoding="utf-8", newline="") as handle:
            text = handle.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError(f"cannot read settings file {path}: {getattr(exc, 'strerror', None) or exc}") from exc
    bom = "\ufeff" if text.startswith("\ufeff") else ""
    try:
        document = tomlkit.parse(text[len(bom):])
    except TOMLKitError as exc:
        raise SettingsError(f"{path}: not valid TOML: {exc}") from exc
    records = []
    for key, value in changes.items():
        table, name = _parent_table(document, key)
        old = table.get(name)
        table[name] = _plain(value)
        records.append(SettingChange(key, None if old is None else _unwrap(old), _plain(value)))
    try:
        # Named as load_settings names it, so relative paths resolve against the folder the next load uses.
        settings = settings_from_mapping(document.unwrap(), source=Path(os.path.abspath(path)))
        for section in package_sections():
            settings.section(section)
    except SettingsError as exc:
        raise SettingsError(f"{exc} (with {', '.join(changes)} changed; not written)") from exc
    out = tomlkit.dumps(document)
    if "\r\n" in text:  # the lines tomlkit adds (a new table) end as the file's do
        out = re.sub(r"(?<!\r)\n", "\r\n", out)
    try:
        _write_atomically(path, bom + out)
    except SettingsError as exc:  # the values may be a long measurement's: said, so they can be typed in
        written = ", ".join(f"{c.key} = {_show(c.new)}" for c in records)
        raise SettingsError(f"{exc}; values not written: {written}") from exc
    return records


def check_writable(path: str | Path) -> None:
    """Raise SettingsError unless the settings file at ``path`` (a link's target) can be rewritten: the
    calibration commands call it before they measure, so that a long run does not end unable to
    write its result.

    A file with no write permission bit is refused as read-only, as editors do, even for root (who
    could write it); so is a file the user cannot write, or one whose folder they cannot write, since
    the file is replaced by a new one written there.
    """
    target = Path(path).resolve()
    try:
        mode = target.stat().st_mode
    except OSError as exc:
        raise SettingsError(f"cannot write settings file {path}: {exc.strerror or exc}") from exc
    if not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        raise SettingsError(f"settings file {path} is read-only (mode {stat.S_IMODE(mode):o}): make it writable "
                            "(chmod u+w) to have calibrated values written into it")
    if not os.access(target, os.W_OK):
        raise SettingsError(f"cannot write settings file {path}: permission denied")
    if not os.access(target.parent, os.W_OK | os.X_OK):
        raise SettingsError(f"cannot write settings file {path}: permission denied to its folder {target.parent}, "
                            "where its new version is written before it replaces the file")


def _unwrap(item: Any) -> Any:
    return item.unwrap() if hasattr(item, "unwrap") else item


def _write_atomically(path: Path, text: str) -> None:
    check_writable(path)
    path = path.resolve()  # a link to the file stays a link: its target is what changes
    mode = stat.S_IMODE(path.stat().st_mode)
    temporary = None
    try:
        descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with open(descriptor, "w", encoding="utf-8", newline="") as handle:  # line ends as the text has them
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except OSError as exc:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
        raise SettingsError(f"cannot write settings file {path}: {exc.strerror or exc}") from exc


def _show(value: Any) -> str:
    if value is None:
        return "(unset)"
    if isinstance(value, list):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    return repr(value)


def format_changes(changes: Iterable[SettingChange]) -> str:
    """One line per change, ``load_cell.counts_per_n: 42000.0 -> 41873.2``."""
    return "\n".join(f"{c.key}: {_show(c.old)} -> {_show(c.new)}" for c in changes)
