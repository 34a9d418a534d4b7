"""A catalogue object as TOML text, for tests that write small catalogues."""

from __future__ import annotations

import json


def object_toml(name: str, shape: str, material: str, modulus_pa: float, **fields: float | list[float]) -> str:
    """One ``[[objects]]`` entry; ``fields`` are the optional keys (``size_m``, ``texture_m``, ...)."""
    lines = ["[[objects]]", f"name = {json.dumps(name)}", f"shape = {json.dumps(shape)}",
             f"material = {json.dumps(material)}", f"modulus_pa = {modulus_pa!r}"]
    lines += [f"{key} = {value!r}" for key, value in fields.items()]
    return "\n" + "\n".join(lines) + "\n"
