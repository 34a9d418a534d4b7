"""Scenes: which objects a demo or session grasps, with which settings.

A scene is one TOML file under ``configs/scenes/`` (or any path): ``description``, ``catalogue``,
``objects`` (names in it, each once), ``grasps_per_object``, ``seed`` and ``settings``. Relative
paths are against the scene file's folder. A scene runs on simulated hardware (``teleop demo``,
``teleop node --scene``); the device backends and the estimator's methods are the settings file's.
"""

from __future__ import annotations

import functools
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import SettingsError
from teleop.settings import Settings, config_dir, default_settings_path, load_settings, resolve_path

__all__ = ["Scene", "current_method", "load_scene", "scene_path"]

SCENE_DIR = config_dir() / "scenes"
_KEYS = ("description", "catalogue", "objects", "grasps_per_object", "seed", "settings")
# Keys a scene may not have, and where what they would say is set.
_MOVED = {
    "backends": "the device backends are the settings file's ([sensors.<finger>], [gripper], [load_cell] and "
                "[display] backend); a scene runs on simulated hardware",
    "estimator": "the estimate methods are the settings file's [estimator] methods",
}


def current_method(name: str) -> str:
    """``name`` as the estimate method is called now: the series fit was ``split`` until the word was left
    to the dataset split, and settings, session logs, datasets and models from before still name it so
    (here, in the base, which every package reads them through)."""
    return "series" if name == "split" else name


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    objects: tuple[ObjectSpec, ...]
    catalogue_path: Path  # the objects' catalogue: a session of the scene is labelled from it
    grasps_per_object: int
    seed: int
    settings_path: Path
    #: Where the settings path was named (``<scene.toml>: settings = "..."``), for the errors reading it.
    settings_named: str = field(default="", compare=False)

    @functools.cached_property
    def settings(self) -> Settings:
        """The scene's settings file, read when first asked for: ``teleop node --scene`` runs with its own
        ``--settings`` and never reads it. Its errors name the scene file and key that named it."""
        try:
            return load_settings(self.settings_path)
        except SettingsError as exc:
            if not self.settings_named:
                raise
            raise SettingsError(_named_in(self.settings_named, self.settings_path, exc)) from exc


def scene_path(name_or_path: str) -> Path:
    """A scene name (``default``) or a path to a scene TOML file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml":
        return candidate
    return SCENE_DIR / f"{name_or_path}.toml"


def _named_path(data: dict, key: str, scene: Path) -> Path | None:
    """The path the scene names under ``key`` (against the scene file's folder), or None."""
    if key not in data:
        return None
    if not isinstance(data[key], str) or not data[key]:
        raise SettingsError(f"{scene}: {key} must be a file path (a string), got {data[key]!r}")
    return resolve_path(data[key], folder=scene.parent)


def _naming(data: dict, key: str, scene: Path) -> str:
    """``<scene>: key = "value"``: where a scene names a file (empty when it names none)."""
    return f"{scene}: {key} = {json.dumps(data[key])}" if key in data else ""


def _named_in(naming: str, path: Path, exc: Exception) -> str:
    """``exc``'s message after ``naming``, with the path it resolved to unless the message names it."""
    message = str(exc)
    return f"{naming}{'' if str(path) in message else f' (resolved to {path})'}: {message}"


def load_scene(name_or_path: str = "default") -> Scene:
    """Load and validate a scene (its settings file is read when first used); errors name the file and the key."""
    path = scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        known = sorted(p.stem for p in SCENE_DIR.glob("*.toml"))
        raise SettingsError(f"no scene {name_or_path!r} ({path}); scenes here: {', '.join(known)}") from None
    except (OSError, ValueError) as exc:  # ValueError: not UTF-8, not TOML, or an integer of over 4300 digits
        raise SettingsError(f"{path}: cannot read scene ({exc})") from exc
    for key in data:
        if key in _MOVED:
            raise SettingsError(f"{path}: {key!r} is no longer a scene key: {_MOVED[key]}; remove it")
        if key not in _KEYS:
            raise SettingsError(f"{path}: unknown key {key!r}; allowed keys: {', '.join(sorted(_KEYS))}")
    if not isinstance(data.get("description", ""), str):
        raise SettingsError(f"{path}: description must be a string, got {data['description']!r}")
    catalogue_path = _named_path(data, "catalogue", path) or config_dir() / "objects.toml"
    try:
        catalogue = {o.name: o for o in load_catalogue(catalogue_path)}
    except SettingsError as exc:
        if "catalogue" not in data:
            raise SettingsError(f"{path}: the shipped catalogue (the scene names no catalogue): {exc}") from exc
        raise SettingsError(_named_in(_naming(data, "catalogue", path), catalogue_path, exc)) from exc
    names = data.get("objects")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise SettingsError(f"{path}: objects must be a non-empty array of object names")
    missing = [n for n in names if n not in catalogue]
    if missing:
        raise SettingsError(f"{path}: objects {missing} are not in the catalogue {catalogue_path}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SettingsError(f"{path}: objects lists {twice[0]!r} twice: name each object once "
                            "(grasps_per_object sets how often each is grasped)")
    grasps = data.get("grasps_per_object", 1)
    seed = data.get("seed", 0)
    for key, value, lo in (("grasps_per_object", grasps, 1), ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            raise SettingsError(f"{path}: {key} must be an integer >= {lo}, got {value!r}")
    return Scene(
        name=path.stem,
        description=data.get("description", ""),
        objects=tuple(catalogue[n] for n in names),
        catalogue_path=catalogue_path,
        grasps_per_object=grasps,
        seed=seed,
        settings_path=_named_path(data, "settings", path) or default_settings_path(),
        settings_named=_naming(data, "settings", path),
    )
