"""The catalogue objects an export labels grasps from (:mod:`teleop.session.export`, "Labels").

By name: the objects of the catalogue given (``--objects``) or stored in the log
(:func:`catalogue_objects`), and those of the catalogues ``teleop label`` took labels from and
attached to the log (:func:`label_catalogue_objects`, :mod:`teleop.session.label`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import SettingsError
from teleop.session.label import label_catalogues
from teleop.session.logdamage import intact_attachment
from teleop.session.logfile import CATALOGUE_ATTACHMENTS, LogInfo

__all__ = ["catalogue_objects", "label_catalogue_objects"]


def _attached_objects(name: str, data: bytes) -> dict[str, ObjectSpec]:
    """Objects by name of the catalogue attached to the log as ``name``; a SettingsError naming the
    attachment (not the temporary file it is read from) when it does not load."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_bytes(data)
        try:
            return {obj.name: obj for obj in load_catalogue(path, recorded=True)}
        except SettingsError as exc:
            raise SettingsError(str(exc).replace(str(path), f"the log's attached {name}")) from exc


def catalogue_objects(info: LogInfo, catalogue: str | Path | None, *, log: Path) -> dict[str, ObjectSpec]:
    """Objects by name: from ``catalogue``, else from the catalogue stored in log ``log`` (refused when
    damaged), else none."""
    if catalogue is not None:
        return {obj.name: obj for obj in load_catalogue(catalogue)}
    for name in CATALOGUE_ATTACHMENTS:
        if (data := intact_attachment(info, name, log=log, instead="pass --objects CATALOGUE")) is not None:
            return _attached_objects(name, data)
    return {}


def label_catalogue_objects(info: LogInfo, *, log: Path) -> dict[str, ObjectSpec]:
    """Objects by name of the catalogues ``teleop label`` attached to log ``log`` (the later one's of a
    name in two; one damaged is refused)."""
    objects: dict[str, ObjectSpec] = {}
    for name in label_catalogues({**info.attachments, **info.damaged_attachments}):
        data = intact_attachment(info, name, log=log, instead="label its grasps again with `teleop label`")
        objects.update(_attached_objects(name, data))
    return objects
