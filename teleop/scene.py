"""Scenes: which objects a demo or session grasps, on which backends, estimated how.

A scene is one TOML file under ``configs/scenes/`` (or any path): ``catalogue``,
``objects`` (names in it), ``grasps_per_object``, ``seed``, ``settings``, a
``[backends]`` table (gripper, camera, load_cell, display) and an
``[estimator]`` table (``methods``). Relative paths are against the scene file's folder.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import SettingsError
from teleop.settings import Settings, config_dir, default_settings_path, load_settings, resolve_path

__all__ = ["Scene", "current_method", "load_scene", "scene_path"]

SCENE_DIR = config_dir() / "scenes"
_BACKENDS = {"gripper": ("sim", "franky"), "camera": ("sim", "opencv"),
             "load_cell": ("sim", "serial", "tcp"), "display": ("sim", "hid")}
_METHODS = ("no_tactile", "elastic", "hertz", "series", "cnn", "hybrid", "auto")


def current_method(name: str) -> str:
    """``name`` as the estimate method is called now: the series fit was ``split`` until the word was left
    to the dataset split, and scenes, settings, session logs, datasets and models from before still name
    it so (here, in the base, as the scenes' method names are: the base cannot import the estimator)."""
    return "series" if name == "split" else name


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    objects: tuple[ObjectSpec, ...]
    grasps_per_object: int
    seed: int
    settings: Settings
    backends: dict[str, str]
    methods: tuple[str, ...]


def scene_path(name_or_path: str) -> Path:
    """A scene name (``default``) or a path to a scene TOML file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml":
        return candidate
    return SCENE_DIR / f"{name_or_path}.toml"


def _named_path(data: dict, key: str, scene: Path) -> Path | None:
    """The path the scene names under ``key`` (against the scene file's folder), or None."""
    return resolve_path(str(data[key]), folder=scene.parent) if key in data else None


def load_scene(name_or_path: str = "default") -> Scene:
    """Load and validate a scene; errors name the file and the key."""
    path = scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        known = sorted(p.stem for p in SCENE_DIR.glob("*.toml"))
        raise SettingsError(f"no scene {name_or_path!r} ({path}); scenes here: {', '.join(known)}") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SettingsError(f"{path}: cannot read scene ({exc})") from exc
    allowed = {"description", "catalogue", "objects", "grasps_per_object", "seed", "settings",
               "backends", "estimator"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise SettingsError(f"{path}: unknown key {unknown[0]!r}; allowed keys: {', '.join(sorted(allowed))}")
    catalogue_path = _named_path(data, "catalogue", path) or config_dir() / "objects.toml"
    catalogue = {o.name: o for o in load_catalogue(catalogue_path)}
    names = data.get("objects")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise SettingsError(f"{path}: objects must be a non-empty array of object names")
    missing = [n for n in names if n not in catalogue]
    if missing:
        raise SettingsError(f"{path}: objects {missing} are not in the catalogue")
    grasps = data.get("grasps_per_object", 1)
    seed = data.get("seed", 0)
    for key, value, lo in (("grasps_per_object", grasps, 1), ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            raise SettingsError(f"{path}: {key} must be an integer >= {lo}, got {value!r}")
    backends = {**{k: "sim" for k in _BACKENDS}, **data.get("backends", {})}
    for key, value in backends.items():
        if key not in _BACKENDS:
            raise SettingsError(f"{path}: unknown backend family {key!r}; families: {', '.join(_BACKENDS)}")
        if value not in _BACKENDS[key]:
            raise SettingsError(f"{path}: backends.{key} = {value!r}: expected one of {_BACKENDS[key]}")
    estimator = data.get("estimator", {})
    methods = tuple(current_method(m) for m in estimator.get("methods", ("series",)))
    bad = [m for m in methods if m not in _METHODS]
    if bad or not methods:
        raise SettingsError(f"{path}: estimator.methods {bad or methods}: expected names from {_METHODS}")
    return Scene(
        name=path.stem,
        description=str(data.get("description", "")),
        objects=tuple(catalogue[n] for n in names),
        grasps_per_object=grasps,
        seed=seed,
        settings=load_settings(_named_path(data, "settings", path) or default_settings_path()),
        backends=backends,
        methods=methods,
    )
