"""A catalogue object as TOML text, and small TOML files and their refusals, for tests that write them."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from teleop.errors import SettingsError


def object_toml(name: str, shape: str, material: str, modulus_pa: float, **fields: float | list[float]) -> str:
    """One ``[[objects]]`` entry; ``fields`` are the optional keys (``size_m``, ``texture_m``, ...)."""
    lines = ["[[objects]]", f"name = {json.dumps(name)}", f"shape = {json.dumps(shape)}",
             f"material = {json.dumps(material)}", f"modulus_pa = {modulus_pa!r}"]
    lines += [f"{key} = {value!r}" for key, value in fields.items()]
    return "\n" + "\n".join(lines) + "\n"


def toml_file(folder: Path, name: str, text: str) -> Path:
    """``text`` written to ``folder / name``: a small catalogue, scene or settings file."""
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def settings_refusal(load: Callable[[], object]) -> str:
    """The message of the SettingsError that ``load()`` raises (the test fails if it raises none)."""
    with pytest.raises(SettingsError) as info:
        load()
    return str(info.value)
