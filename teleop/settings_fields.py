"""The vocabulary settings are written in: fields with their allowed values, checked on construction,
and the building of a settings dataclass from TOML-shaped data with errors that name the file and key.

:mod:`teleop.settings` (the rig's tables) and the packages' own tables (``estimator.settings``,
``haptics.settings``) are written in it.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar
from urllib.parse import urlsplit

from teleop.errors import SettingsError

__all__ = ["Validated", "build_settings", "spec", "tcp_host_port"]

T = TypeVar("T")


def spec(
    default: Any = dataclasses.MISSING,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    choices: tuple[Any, ...] | None = None,
    length: int | None = None,
    doc: str = "",
    default_factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with its allowed range, checked on construction.

    ``lo``/``hi`` bound numbers (and every number inside a tuple); ``lo_open``
    makes the lower bound exclusive; ``choices`` lists allowed values;
    ``length`` fixes a tuple's length.
    """
    meta = {"lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices, "length": length, "doc": doc}
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _allowed(meta: Mapping[str, Any]) -> str:
    if meta.get("choices"):
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    lo, hi = meta.get("lo"), meta.get("hi")
    left = "(" if meta.get("lo_open") else "["
    if lo is not None and hi is not None:
        return f"a value in {left}{lo}, {hi}]"
    if lo is not None:
        return f"a value {'>' if meta.get('lo_open') else '>='} {lo}"
    if hi is not None:
        return f"a value <= {hi}"
    return "any value"


def _iter_numbers(value: Any):
    if isinstance(value, tuple):
        for item in value:
            yield from _iter_numbers(item)
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield value


class Validated:
    """Mixin: check every field against its ``spec`` when the object is built."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            meta = f.metadata
            value = getattr(self, f.name)
            where = f"{type(self).__name__}.{f.name}"
            choices = meta.get("choices")
            if choices is not None and isinstance(value, tuple):  # a list: each element is one of them
                for i, item in enumerate(value):
                    if item not in choices:
                        raise SettingsError(f"{where}[{i}] = {item!r}: expected {_allowed(meta)}")
            elif choices is not None and value not in choices:
                raise SettingsError(f"{where} = {value!r}: expected {_allowed(meta)}")
            if meta.get("length") is not None and len(value) != meta["length"]:
                raise SettingsError(
                    f"{where} has {len(value)} entries: expected exactly {meta['length']}"
                )
            lo, hi = meta.get("lo"), meta.get("hi")
            for number in _iter_numbers(value):
                try:
                    bad = not math.isfinite(number)
                except OverflowError:  # an integer too large for a float: refused, not a traceback
                    bad = True
                if lo is not None:
                    bad |= number <= lo if meta.get("lo_open") else number < lo
                if hi is not None:
                    bad |= number > hi
                if bad:
                    raise SettingsError(f"{where} = {value!r}: expected {_allowed(meta)}")
        self._check()

    def _check(self) -> None:
        """Cross-field checks; override where fields constrain each other."""


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _coerce(value: Any, tp: Any, key: str, source: str) -> Any:
    """Check ``value`` read from TOML against annotation ``tp``; return it in that type."""
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise SettingsError(f"{source}: [{key}] must be a table, got {type(value).__name__}")
        return build_settings(tp, value, source, key)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list | tuple):
            raise SettingsError(f"{source}: {key} must be an array, got {type(value).__name__}")
        if args[-1] is Ellipsis:
            args = (args[0],) * len(value)
        elif len(value) != len(args):
            raise SettingsError(f"{source}: {key} must have {len(args)} entries, got {len(value)}")
        return tuple(_coerce(v, a, f"{key}[{i}]", source) for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if tp is bool:
        if not isinstance(value, bool):
            raise SettingsError(f"{source}: {key} must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SettingsError(f"{source}: {key} must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SettingsError(f"{source}: {key} must be a number, got {value!r}")
        try:
            return float(value)
        except OverflowError:  # an integer beyond any float: its digits are no use in the message
            raise SettingsError(f"{source}: {key} is an integer too large for a number: expected a finite "
                                "number (below 1.8e308)") from None
    if tp is str:
        if not isinstance(value, str):
            raise SettingsError(f"{source}: {key} must be a string, got {value!r}")
        return value
    raise SettingsError(f"{source}: {key} has unsupported type {_type_name(tp)}")


def build_settings(cls: type[T], data: Mapping[str, Any], source: str, prefix: str, *,
                   built: Mapping[str, Any] | None = None, others: Iterable[str] = ()) -> T:
    """Build the settings dataclass ``cls`` from ``data``; errors name ``source`` and the key.

    ``built`` holds values of keys of ``data`` the caller built itself (e.g. a table of tables);
    ``others`` keys the table may also have that others build (the packages' tables at the top
    level): not in ``data``, but named among the allowed keys when a key is unknown.
    """
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls)  # type: ignore[arg-type]
             if f.init and f.metadata.get("key", True)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        where = f"[{prefix}]" if prefix else "top level"
        allowed = ", ".join(sorted({*names, *others}))
        raise SettingsError(f"{source}: unknown key {unknown[0]!r} in {where}; allowed keys: {allowed}")
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        kwargs[name] = built[name] if built and name in built else _coerce(value, tp, key, source)
    try:
        return cls(**kwargs)
    except SettingsError as exc:
        where = f"[{prefix}] " if prefix else ""
        raise SettingsError(f"{source}: {where}{exc}") from None


def tcp_host_port(address: str) -> tuple[str, int] | None:
    """``("host", port)`` of ``tcp://host:port`` (port 1..65535); None for anything else."""
    parts = urlsplit(address)
    try:
        port = parts.port
    except ValueError:  # out of 0..65535
        return None
    return (parts.hostname, port) if parts.scheme == "tcp" and parts.hostname and port else None
