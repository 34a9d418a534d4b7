"""The checks bus message fields are written in: the vocabulary of :mod:`teleop.bus.messages`.

The wire format itself (frames, header, limits) is :mod:`teleop.bus.wire`'s, and which fields
each message type has is :mod:`teleop.bus.messages`' (one dataclass per type); this module says
what a field check is, provides the kinds the types use (bounded strings, integers, finite
numbers, flags, intervals, maps of names to numbers, and typed arrays), how a body dataclass
declares its fields with them (:func:`scalar`, :func:`array`), and the :class:`Schema` the wire
checks a body against, derived from such a dataclass (:meth:`Schema.of`). Each kind of check is
a frozen dataclass whose attributes are its options, so other views of a message type (the
session log's JSON Schemas, :mod:`teleop.session.foxglove`) read the same definitions.

Every check refuses with :class:`~teleop.errors.MessageRejected` (``mistyped_field``,
or ``not_finite`` for NaN and infinity), naming the field.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop.errors import MessageRejected

__all__ = [
    "FLAG",
    "INTERVAL",
    "ArrayField",
    "Check",
    "FlagField",
    "IntegerField",
    "IntervalField",
    "NumberField",
    "NumberMapField",
    "Schema",
    "TextField",
    "array",
    "is_int",
    "scalar",
]


def is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


# A field check is a frozen description of the field (its options are its attributes, so the
# session log derives a JSON Schema from them) that, called with (value, where), returns the
# value in its wire form (plain Python types) or raises MessageRejected naming the field.


@dataclass(frozen=True)
class TextField:
    """A string of at most ``max_chars`` characters, one of ``choices`` when given; nil if ``nullable``."""

    choices: tuple[str, ...] | None = None
    nullable: bool = False
    max_chars: int = 256

    def __call__(self, value: Any, where: str) -> str | None:
        if value is None and self.nullable:
            return None
        if not isinstance(value, str):
            raise MessageRejected("mistyped_field", f"{where} must be a string, got {type(value).__name__}")
        if self.choices is not None and value not in self.choices:
            raise MessageRejected("mistyped_field", f"{where} = {value!r}: expected one of {', '.join(self.choices)}")
        if len(value) > self.max_chars:
            raise MessageRejected("mistyped_field", f"{where} has {len(value)} characters, at most {self.max_chars}")
        return value


@dataclass(frozen=True)
class IntegerField:
    """An integer >= ``lo``; nil if ``nullable``."""

    lo: int = 0
    nullable: bool = False

    def __call__(self, value: Any, where: str) -> int | None:
        if value is None and self.nullable:
            return None
        if not is_int(value):
            raise MessageRejected("mistyped_field", f"{where} must be an integer, got {value!r}")
        if value < self.lo:
            raise MessageRejected("mistyped_field", f"{where} = {value}: expected >= {self.lo}")
        return int(value)


#: The largest time (s, either sign) a message carries: any clock the bus uses (monotonic since boot,
#: or the Unix epoch: 1.8e9 s in 2027) stays within it, and in nanoseconds it fits an int64 (9.2e9 s),
#: as the session log and Foxglove store it. A time beyond it would break those, not just be wrong.
MAX_TIME_S = 4.0e9


@dataclass(frozen=True)
class NumberField:
    """A finite number, above ``lo`` (strictly if ``lo_open``) when given, at most ``max_abs`` in
    magnitude when given; nil if ``nullable``."""

    lo: float | None = None
    lo_open: bool = False
    nullable: bool = False
    max_abs: float | None = None

    @property
    def positive(self) -> bool:
        """Whether the number is > 0 (a modulus, a period)."""
        return self.lo == 0 and self.lo_open

    def __call__(self, value: Any, where: str) -> float | None:
        if value is None and self.nullable:
            return None
        if not isinstance(value, numbers.Real) or isinstance(value, bool | np.bool_):
            raise MessageRejected("mistyped_field", f"{where} must be a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number):
            raise MessageRejected("not_finite", f"{where} = {number}: expected a finite number")
        if self.max_abs is not None and abs(number) > self.max_abs:
            raise MessageRejected("mistyped_field", f"{where} = {number:.6g}: expected at most {self.max_abs:g} in magnitude")
        lo = self.lo
        if lo is not None and (number <= lo if self.lo_open else number < lo):
            raise MessageRejected("mistyped_field", f"{where} = {number}: expected {'>' if self.lo_open else '>='} {lo}")
        return number


@dataclass(frozen=True)
class FlagField:
    """True or false."""

    nullable = False

    def __call__(self, value: Any, where: str) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise MessageRejected("mistyped_field", f"{where} must be true or false, got {value!r}")
        return bool(value)


_BOUND = NumberField(lo=0.0, lo_open=True, nullable=True)


@dataclass(frozen=True)
class IntervalField:
    """``[low, high]`` of moduli (Pa), each > 0 or nil (an open side), low <= high."""

    nullable = False

    def __call__(self, value: Any, where: str) -> list[float | None]:
        if not isinstance(value, list | tuple) or len(value) != 2:
            raise MessageRejected("mistyped_field", f"{where} must be [low, high] (each a number or nil), got {value!r}")
        low, high = _BOUND(value[0], f"{where}[0]"), _BOUND(value[1], f"{where}[1]")
        if low is not None and high is not None and low > high:
            raise MessageRejected("mistyped_field", f"{where} = [{low}, {high}]: low is above high")
        return [low, high]


_NAME, _NUMBER = TextField(max_chars=64), NumberField()


@dataclass(frozen=True)
class NumberMapField:
    """A map of at most ``max_items`` names (64 characters at most) to finite numbers."""

    max_items: int
    nullable = False

    def __call__(self, value: Any, where: str) -> dict[str, float]:
        if not isinstance(value, Mapping) or len(value) > self.max_items:
            raise MessageRejected("mistyped_field",
                                  f"{where} must be a map of at most {self.max_items} name -> number")
        out = {}
        for key, item in value.items():
            name = _NAME(key, f"{where} key")
            out[name] = _NUMBER(item, f"{where}.{name}")
        return out


#: Every kind of scalar field check.
Check = TextField | IntegerField | NumberField | FlagField | IntervalField | NumberMapField
#: The checks without options.
FLAG, INTERVAL = FlagField(), IntervalField()


@dataclass(frozen=True)
class ArrayField:
    """An array field: allowed dtypes, allowed ndims, whether floats must be finite."""

    dtypes: tuple[str, ...]
    ndims: tuple[int, ...]
    finite: bool = False
    max_abs: float | None = None  # float values at most this in magnitude

    def coerce(self, value: Any, where: str) -> np.ndarray:
        """Sender side: arrays as given (checked later, never cast); bytes and numbers converted,
        flags refused (``[True, 3.0]`` would be sent as ``[1.0, 3.0]``)."""
        if isinstance(value, bytes | bytearray | memoryview):
            value = np.frombuffer(value, dtype=np.uint8)
        elif not isinstance(value, np.ndarray):
            try:
                if isinstance(value, str) or not isinstance(value, numbers.Real | Sequence):
                    raise TypeError(type(value).__name__)
                flag = _first_flag(value)
                converted = np.atleast_1d(np.asarray(value, dtype=np.dtype(self.dtypes[0])))
            except (TypeError, ValueError) as exc:
                raise MessageRejected("mistyped_field", f"{where} must be an array of numbers ({exc})") from exc
            if flag is not None:
                raise MessageRejected("mistyped_field", f"{where} must be an array of numbers, not of flags: holds {flag!r}")
            value = converted
        return value

    def check(self, array: np.ndarray, where: str) -> np.ndarray:
        if array.dtype.newbyteorder("=") not in {np.dtype(d).newbyteorder("=") for d in self.dtypes}:
            allowed = ", ".join(np.dtype(d).name for d in self.dtypes)
            raise MessageRejected("mistyped_field", f"{where} has dtype {array.dtype.name}: expected {allowed}")
        if array.ndim not in self.ndims:
            raise MessageRejected("mistyped_field", f"{where} is {array.ndim}-D: expected {' or '.join(map(str, self.ndims))}-D")
        if self.finite and array.dtype.kind == "f" and not np.isfinite(array).all():
            raise MessageRejected("not_finite", f"{where} holds NaN or infinity")
        if self.max_abs is not None and array.dtype.kind == "f" and array.size and np.abs(array).max() > self.max_abs:
            raise MessageRejected("mistyped_field", f"{where} holds {np.abs(array).max():.6g}: expected values at most "
                                                  f"{self.max_abs:g} in magnitude")
        return array


def _first_flag(value: Any) -> bool | np.bool_ | None:
    """The first flag in a number or (nested) sequence of numbers, None when it holds none."""
    try:
        items = np.asarray(value, dtype=object).flat
    except ValueError:  # ragged: the conversion to numbers refuses it
        return None
    return next((item for item in items if isinstance(item, bool | np.bool_)), None)


# How a body dataclass field says what it is (dataclasses.Field.metadata keys).
_CHECK, _ARRAY, _ADDED = "bus_check", "bus_array", "bus_added_later"


def scalar(check: Check, *, required: bool = False, added_later: bool = False) -> Any:
    """A scalar body field checked by ``check``, as a :func:`dataclasses.field`.

    Parameters
    ----------
    check : Check
        What the field's value must be.
    required : bool
        For a nullable field: a sender must give it (nil included). Otherwise a sender may leave
        a nullable field out, and it is sent as nil (its dataclass default is None).
    added_later : bool
        The field came after its type was first sent: a receiver reads a message without it (an
        older sender, an older session log) as nil. Such a field is nullable and never required.

    Raises
    ------
    TypeError
        ``required`` or ``added_later`` for a field they cannot apply to (a mistake in a type's
        definition).
    """
    if added_later and (required or not check.nullable):
        raise TypeError(f"a field added later must be nullable and not required, not {check!r}")
    if required and not check.nullable:
        raise TypeError(f"only a nullable field can be required: {check!r} always is")
    metadata = {_CHECK: check, _ADDED: added_later}
    if check.nullable and not required:
        return field(default=None, metadata=metadata)
    return field(metadata=metadata)


def array(spec: ArrayField) -> Any:
    """An array body field of ``spec``, as a :func:`dataclasses.field` (it travels as a buffer)."""
    return field(metadata={_ARRAY: spec})


@dataclass(frozen=True)
class Schema:
    """Body of one message type: scalar fields, array fields, cross-field rule."""

    fields: Mapping[str, Check]
    arrays: Mapping[str, ArrayField] = field(default_factory=dict)
    nullable: frozenset[str] = frozenset()  # fields a sender may leave out (filled with nil)
    rule: Callable[[dict[str, Any]], None] | None = None
    # Nullable fields added after the type was first sent: a receiver fills them with nil when a
    # sender (or a logged message) predates them; senders always send them.
    optional: frozenset[str] = frozenset()

    @classmethod
    def of(cls, body: type) -> Schema:
        """The schema a body dataclass declares.

        Its fields, in order, each made with :func:`scalar` or :func:`array`; its rule, when it
        has a ``cross_check`` method: called on the body built from the checked fields, it raises
        :class:`~teleop.errors.MessageRejected` for fields that disagree.

        Raises
        ------
        TypeError
            ``body`` is not a dataclass, or a field of it is not declared with :func:`scalar` or
            :func:`array`.
        """
        if not dataclasses.is_dataclass(body):
            raise TypeError(f"{body!r} is not a dataclass: a message body is one")
        scalars: dict[str, dataclasses.Field] = {}
        arrays: dict[str, ArrayField] = {}
        for item in dataclasses.fields(body):
            if _ARRAY in item.metadata:
                arrays[item.name] = item.metadata[_ARRAY]
            elif _CHECK in item.metadata:
                scalars[item.name] = item
            else:
                raise TypeError(f"{body.__name__}.{item.name} is declared without scalar() or array()")
        return cls(
            fields={name: item.metadata[_CHECK] for name, item in scalars.items()},
            arrays=arrays,
            nullable=frozenset(name for name, item in scalars.items() if item.default is None),
            rule=_CrossCheck(body) if hasattr(body, "cross_check") else None,
            optional=frozenset(name for name, item in scalars.items() if item.metadata[_ADDED]),
        )


@dataclass(frozen=True)
class _CrossCheck:
    """A body class's ``cross_check`` as a schema's rule: run on the body built from the checked fields."""

    body: type

    def __call__(self, checked: dict[str, Any]) -> None:
        self.body(**checked).cross_check()
