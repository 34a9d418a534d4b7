"""Where settings files and the paths they name lie: the shipped configs folder, and how a relative
path in a settings or scene file resolves (against the folder of the file that names it).

:mod:`teleop.settings` re-exports these; they live apart to keep that module within its size.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

__all__ = ["CONFIG_DIR", "config_dir", "default_settings_path", "resolve_path", "settings_folder"]


def config_dir() -> Path:
    """The folder of the shipped configs (``configs/``: settings, rigs, scenes, catalogue, calibrations).

    An installed wheel carries it as package data in ``teleop/_configs`` (``pyproject.toml`` maps
    the package ``teleop._configs`` onto the top-level ``configs/`` folder); a source checkout,
    editable installs included, has it beside the packages.
    """
    shipped = importlib.resources.files("teleop") / "_configs"
    if isinstance(shipped, Path) and shipped.is_dir():
        return shipped
    return Path(__file__).resolve().parent.parent / "configs"


#: :func:`config_dir` when this module was imported.
CONFIG_DIR = config_dir()


def resolve_path(value: str | os.PathLike[str], *, folder: Path | None = None) -> Path:
    """Where a path named in a settings or scene file points (``SensorSettings.calibration``,
    ``SimulationSettings.background``, ``BusSettings.keys_dir``, the estimator's ``model_path``, a
    scene's ``settings`` and ``catalogue``): ``~`` expanded to the home folder, an absolute path as it is, a
    relative one against ``folder``, the folder of the file that names it. Loading a file resolves its paths, so settings and the records made with
    them carry absolute ones; ``folder`` None (a path from settings built in code, or from a record
    of an older version) means :func:`config_dir`."""
    path = Path(os.path.expanduser(value))  # ~/keys, as `teleop keys --help` writes it; an unknown ~user stays
    if path.is_absolute():
        return path
    return Path(os.path.normpath((config_dir() if folder is None else folder) / path))  # no "a/../"


def settings_folder(source: Path | None) -> Path:
    """Where relative paths in the settings file ``source`` point from: the folder of the file
    itself, through any symbolic link to it (where its calibrations and edits live), or
    :func:`config_dir` for settings built in code (None)."""
    return config_dir() if source is None else source.resolve().parent


def default_settings_path() -> Path:
    """Path of the settings file shipped in ``configs/`` (simulated hardware)."""
    return config_dir() / "settings.toml"
