"""The calibration files an exported record carries (:mod:`teleop.session.export`, "Records travel")."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from teleop.errors import SessionLogError
from teleop.record import calibration_copy
from teleop.session.logdamage import intact_attachment
from teleop.session.logfile import LogInfo
from teleop.settings import Settings, resolve_path

__all__ = ["carried_calibrations"]

log = logging.getLogger("teleop.session.export")  # its warnings are export's


def carried_calibrations(
    info: LogInfo, settings: Settings, path: Path, *, disk_first: bool
) -> tuple[Settings, dict[str, bytes]]:
    """The calibration file of every sensor that names one, to carry in the records (module notes).

    Returns ``settings`` with each such sensor pointing at a copy of the file
    (:func:`~teleop.record.calibration_copy`), and finger -> the file's bytes.
    """
    sensors, files = [], {}
    for sensor in settings.sensors:
        if not sensor.calibration:
            sensors.append(sensor)
            continue
        stored = f"calibration/{sensor.finger}/{Path(sensor.calibration).name}"
        disk = resolve_path(sensor.calibration)

        def from_disk(disk: Path = disk) -> bytes | None:
            try:
                return disk.read_bytes() if disk.is_file() else None
            except OSError:
                return None

        def from_log(stored: str = stored, finger: str = sensor.finger) -> bytes | None:
            return intact_attachment(info, stored, log=path, instead=f"pass --settings whose sensor {finger!r} "
                                     "names an intact copy of its calibration file")

        data = None
        for source in (from_disk, from_log) if disk_first else (from_log, from_disk):
            data = source()
            if data is not None:
                break
        if data is None:
            log.warning(
                "%s: sensor %r names calibration %s, which is neither stored in the log nor on this "
                "machine; its records name it without carrying it",
                path, sensor.finger, sensor.calibration,
            )
            sensors.append(sensor)
            continue
        try:
            copy = calibration_copy(data, Path(sensor.calibration).name)
        except OSError as exc:
            raise SessionLogError(
                f"cannot copy the calibration of sensor {sensor.finger!r} to a cache folder: "
                f"{exc.strerror or exc}"
            ) from exc
        files[sensor.finger] = data
        sensors.append(dataclasses.replace(sensor, calibration=str(copy)))
    return dataclasses.replace(settings, sensors=tuple(sensors)), files
