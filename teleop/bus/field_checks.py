"""The checks bus message fields are written in: the vocabulary of :data:`teleop.bus.wire.SCHEMAS`.

The wire format itself (frames, header, limits, which fields each message type has)
is :mod:`teleop.bus.wire`'s; this module only says what a field check is and
provides the kinds the schemas use: bounded strings, integers, finite numbers,
flags, intervals, maps of names to numbers, and typed arrays.

Every check refuses with :class:`~teleop.errors.MessageRejected` (``mistyped_field``,
or ``not_finite`` for NaN and infinity), naming the field.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop.errors import MessageRejected

__all__ = [
    "ArrayField",
    "Check",
    "Schema",
    "flag_field",
    "integer_field",
    "interval_field",
    "is_int",
    "number_field",
    "number_map_field",
    "text_field",
]


# Each check takes (value, where) and returns the value in its wire form (plain Python
# types; arrays for array fields) or raises MessageRejected naming the field.

Check = Callable[[Any, str], Any]


def is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def text_field(*, choices: tuple[str, ...] | None = None, nullable: bool = False, max_chars: int = 256) -> Check:
    def check(value: Any, where: str) -> str | None:
        if value is None and nullable:
            return None
        if not isinstance(value, str):
            raise MessageRejected("mistyped_field", f"{where} must be a string, got {type(value).__name__}")
        if choices is not None and value not in choices:
            raise MessageRejected("mistyped_field", f"{where} = {value!r}: expected one of {', '.join(choices)}")
        if len(value) > max_chars:
            raise MessageRejected("mistyped_field", f"{where} has {len(value)} characters, at most {max_chars}")
        return value

    return check


def integer_field(*, lo: int = 0) -> Check:
    def check(value: Any, where: str) -> int:
        if not is_int(value):
            raise MessageRejected("mistyped_field", f"{where} must be an integer, got {value!r}")
        if value < lo:
            raise MessageRejected("mistyped_field", f"{where} = {value}: expected >= {lo}")
        return int(value)

    return check


def number_field(*, lo: float | None = None, lo_open: bool = False, nullable: bool = False) -> Check:
    def check(value: Any, where: str) -> float | None:
        if value is None and nullable:
            return None
        if not isinstance(value, numbers.Real) or isinstance(value, bool | np.bool_):
            raise MessageRejected("mistyped_field", f"{where} must be a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number):
            raise MessageRejected("not_finite", f"{where} = {number}: expected a finite number")
        if lo is not None and (number <= lo if lo_open else number < lo):
            raise MessageRejected("mistyped_field", f"{where} = {number}: expected {'>' if lo_open else '>='} {lo}")
        return number

    return check


def flag_field(value: Any, where: str) -> bool:
    if not isinstance(value, bool | np.bool_):
        raise MessageRejected("mistyped_field", f"{where} must be true or false, got {value!r}")
    return bool(value)


def interval_field(value: Any, where: str) -> list[float | None]:
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise MessageRejected("mistyped_field", f"{where} must be [low, high] (each a number or nil), got {value!r}")
    bound = number_field(lo=0.0, lo_open=True, nullable=True)
    low, high = bound(value[0], f"{where}[0]"), bound(value[1], f"{where}[1]")
    if low is not None and high is not None and low > high:
        raise MessageRejected("mistyped_field", f"{where} = [{low}, {high}]: low is above high")
    return [low, high]


def number_map_field(*, max_items: int) -> Check:
    """A map of at most ``max_items`` names (64 characters at most) to finite numbers."""

    def check(value: Any, where: str) -> dict[str, float]:
        if not isinstance(value, Mapping) or len(value) > max_items:
            raise MessageRejected("mistyped_field", f"{where} must be a map of at most {max_items} name -> number")
        number = number_field()
        out = {}
        for key, item in value.items():
            name = text_field(max_chars=64)(key, f"{where} key")
            out[name] = number(item, f"{where}.{name}")
        return out

    return check


@dataclass(frozen=True)
class ArrayField:
    """An array field: allowed dtypes, allowed ndims, whether floats must be finite."""

    dtypes: tuple[str, ...]
    ndims: tuple[int, ...]
    finite: bool = False

    def coerce(self, value: Any, where: str) -> np.ndarray:
        """Sender side: arrays as given (checked later, never cast); bytes and numbers converted."""
        if isinstance(value, bytes | bytearray | memoryview):
            value = np.frombuffer(value, dtype=np.uint8)
        elif not isinstance(value, np.ndarray):
            try:
                if isinstance(value, str) or not isinstance(value, numbers.Real | Sequence):
                    raise TypeError(type(value).__name__)
                value = np.atleast_1d(np.asarray(value, dtype=np.dtype(self.dtypes[0])))
            except (TypeError, ValueError) as exc:
                raise MessageRejected("mistyped_field", f"{where} must be an array of numbers ({exc})") from exc
        return value

    def check(self, array: np.ndarray, where: str) -> np.ndarray:
        if array.dtype.newbyteorder("=") not in {np.dtype(d).newbyteorder("=") for d in self.dtypes}:
            allowed = ", ".join(np.dtype(d).name for d in self.dtypes)
            raise MessageRejected("mistyped_field", f"{where} has dtype {array.dtype.name}: expected {allowed}")
        if array.ndim not in self.ndims:
            raise MessageRejected("mistyped_field", f"{where} is {array.ndim}-D: expected {' or '.join(map(str, self.ndims))}-D")
        if self.finite and array.dtype.kind == "f" and not np.isfinite(array).all():
            raise MessageRejected("not_finite", f"{where} holds NaN or infinity")
        return array


@dataclass(frozen=True)
class Schema:
    """Body of one message type: scalar fields, array fields, cross-field rule."""

    fields: Mapping[str, Check]
    arrays: Mapping[str, ArrayField] = field(default_factory=dict)
    nullable: frozenset[str] = frozenset()  # fields a sender may leave out (filled with nil)
    rule: Callable[[dict[str, Any]], None] | None = None
