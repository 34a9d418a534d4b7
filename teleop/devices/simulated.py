"""Whether a robot device backend, or the whole configured robot, is simulated.

Each backend class says it (:attr:`~teleop.devices.base.Device.simulated`); this module asks
it through the families' name tables (``BACKENDS``), importing only the families asked about.
"""

from __future__ import annotations

import importlib
import logging

from teleop.devices.base import load_backend
from teleop.errors import BackendNotFoundError
from teleop.settings import Settings

__all__ = ["FAMILIES", "is_simulated", "robot_is_simulated"]

log = logging.getLogger(__name__)

#: Device family (``Device.family``) -> the module holding its ``BACKENDS`` table.
FAMILIES = {
    "gripper": "teleop.devices.gripper",
    "camera": "teleop.devices.camera",
    "load cell": "teleop.devices.loadcell",
}


def is_simulated(family: str, backend: str) -> bool:
    """Whether ``backend`` of device ``family`` (a key of :data:`FAMILIES`) is simulated.

    A backend whose module or library cannot be imported, for whatever reason, counts as hardware:
    simulated backends need nothing beyond the package's own dependencies.

    Raises
    ------
    ValueError
        ``family`` is not a key of :data:`FAMILIES`.
    BackendNotFoundError
        ``backend`` is not in the family's table (the message lists the names there are).
    """
    if family not in FAMILIES:
        raise ValueError(f"no device family {family!r}; expected one of {', '.join(FAMILIES)}")
    backends = importlib.import_module(FAMILIES[family]).BACKENDS
    if backend not in backends:
        load_backend(family, backends, backend)  # raises, listing the names there are
    try:
        cls = load_backend(family, backends, backend)
    except BackendNotFoundError:  # a library not installed: a hardware backend's
        return False
    except Exception as exc:  # noqa: BLE001 - a broken library (OSError, ...) must not stop a recording
        log.warning("%s backend %r does not import (%s: %s): taken as hardware", family, backend,
                    type(exc).__name__, exc)
        return False
    return bool(cls.simulated)


def robot_is_simulated(settings: Settings) -> bool:
    """Whether the gripper, the load cell and every sensor's camera of ``settings`` are all simulated."""
    return (is_simulated("gripper", settings.gripper.backend)
            and is_simulated("load cell", settings.load_cell.backend)
            and all(is_simulated("camera", s.camera_backend) for s in settings.sensors))
