"""Reading the published dataset's files: pickles that admit numpy arrays only, layout folders.

Pickles execute code on load, so every ``.pkl`` of the dataset is read with
:func:`safe_load_pickle`, which admits numpy arrays and nothing else
(:func:`load_pickled_array` on top of it checks for a finite numeric array of the
expected shape). Lists, tuples and dicts around the arrays are walked once each and
bounded (:data:`MAX_PICKLE_DEPTH` and the other ``MAX_PICKLE_*`` budgets), so a small
pickle of shared references cannot make the check or ``np.asarray`` run or allocate
without end. Forces and widths, in both layouts, must be physically possible
(:func:`check_forces`, :func:`check_widths`). The layouts name their folders
``<key>=<integer>`` (:func:`layout_index`); a folder's files are required by name
(:func:`layout_member`).
"""

from __future__ import annotations

import codecs
import io
import math
import os
import pickle
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy._core.multiarray import _reconstruct, scalar
from numpy._core.numeric import _frombuffer

from teleop.errors import DatasetError, UnsafePickleError

__all__ = [
    "FORCE_TOLERANCE_N",
    "MAX_PICKLE_BYTES",
    "MAX_PICKLE_DEPTH",
    "MAX_PICKLE_ELEMENTS",
    "MAX_PICKLE_ITEMS",
    "WIDTH_SLACK_M",
    "array_from_pickle",
    "check_forces",
    "check_widths",
    "find_layout_folders",
    "layout_index",
    "layout_member",
    "load_pickled_array",
    "safe_load_pickle",
]

# --------------------------------------------------------------------------- safe unpickling


class _Refused(Exception):
    """An admitted global was asked to build something outside a plain numpy array."""


class _PickledNdarrayType:
    """Stands for ``numpy.ndarray`` inside a pickle: only :func:`_reconstruct_array` accepts it.

    Handing out the real class would let a pickle call ``ndarray(shape)`` directly and
    allocate whatever it asks for.
    """

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        raise _Refused("a direct call of numpy.ndarray (arrays are rebuilt through _reconstruct only)")


def _reconstruct_array(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    # numpy always pickles an empty (0,) placeholder and fills it from the pickled state;
    # any other shape would only serve to allocate memory.
    if subtype is not _PickledNdarrayType or tuple(shape) != (0,):
        raise _Refused(f"_reconstruct of {subtype!r} with shape {shape!r} (only numpy's empty placeholder is admitted)")
    return _reconstruct(np.ndarray, (0,), dtype)


_LATIN1_NAMES = ("latin1", "latin-1", "iso-8859-1", "iso8859-1", "l1")


def _latin1_encode(text: str, encoding: str = "latin1", errors: str = "strict") -> bytes:
    # Protocol 0-2 pickles carry array bytes as latin-1 text; admit no other codec.
    # Compared by name, not looked up: a codec lookup may import a module.
    if not isinstance(encoding, str) or encoding.lower().replace("_", "-") not in _LATIN1_NAMES:
        raise _Refused(f"_codecs.encode with codec {encoding!r} (only latin-1 is admitted)")
    return codecs.encode(text, "latin1", errors)


# Every global a pickled numpy array, dtype or scalar names (numpy 2 ``numpy._core`` and the
# ``numpy.core`` names of pickles written by numpy 1), mapped to what it may build.
_ADMITTED_GLOBALS: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): _PickledNdarrayType,
    ("numpy", "dtype"): np.dtype,
    ("numpy._core.multiarray", "_reconstruct"): _reconstruct_array,
    ("numpy.core.multiarray", "_reconstruct"): _reconstruct_array,
    ("numpy._core.multiarray", "scalar"): scalar,
    ("numpy.core.multiarray", "scalar"): scalar,
    ("numpy._core.numeric", "_frombuffer"): _frombuffer,
    ("numpy.core.numeric", "_frombuffer"): _frombuffer,
    ("_codecs", "encode"): _latin1_encode,
}


# numpy dtype flags a plain array's dtype may carry (NPY_NEEDS_INIT, NPY_NEEDS_PYAPI: text and
# structured dtypes); any other (NPY_ITEM_REFCOUNT, NPY_LIST_PICKLE, NPY_ITEM_IS_POINTER, ...) makes
# numpy treat an item as Python object pointers.
_PLAIN_DTYPE_FLAGS = 0x08 | 0x10


def _check_build(inst: Any, state: Any) -> None:
    """Refuse a BUILD (``__setstate__``) other than of a plain array or dtype, before it runs.

    numpy's ``ndarray.__setstate__`` fills an object array from a list without checking its
    length (a short list crashes the process), and ``dtype.__setstate__`` takes its flags from
    the pickle (flags that mark a plain dtype as holding objects lead there too), so neither may
    see an object dtype or object flags; numpy itself pickles no other BUILD. Nor does it check
    a structured or subarray dtype's layout against its item size (:func:`_check_layout`).
    """
    if isinstance(inst, np.dtype):
        flags = state[7] if isinstance(state, tuple) and len(state) >= 8 else 0
        if not isinstance(flags, int) or flags & ~_PLAIN_DTYPE_FLAGS:
            raise _Refused(f"a dtype state with object flags {flags!r} (object arrays are not admitted)")
        _check_layout(state)
    elif type(inst) is np.ndarray:
        dtype = state[-3] if isinstance(state, tuple) and len(state) in (4, 5) else None
        if isinstance(dtype, np.dtype) and (dtype.hasobject or dtype.flags & ~_PLAIN_DTYPE_FLAGS):
            raise _Refused(f"an object array (dtype {dtype}, flags {dtype.flags})")
    else:
        raise _Refused(f"the state of a {type(inst).__name__} (only numpy arrays and dtypes take one)")


def _check_layout(state: tuple) -> None:
    """Refuse a dtype state whose fields or subarray do not lie within its items: numpy reads a field
    at the offset the state gives (a list of arrays of a dtype whose field lies far outside its
    items crashes ``np.asarray``)."""
    subarray, names, fields, item_bytes = state[2:6]
    if subarray is None and names is None and fields is None:
        return
    if not (isinstance(item_bytes, int) and item_bytes >= 0):
        raise _Refused(f"a dtype state with fields or a subarray and an item size of {item_bytes!r}")
    if subarray is not None:
        base, shape = subarray if isinstance(subarray, tuple) and len(subarray) == 2 else (None, None)
        if not (isinstance(base, np.dtype) and isinstance(shape, tuple)
                and all(isinstance(n, int) and n >= 0 for n in shape)
                and base.itemsize * math.prod(shape) == item_bytes):
            raise _Refused(f"a subarray dtype state {subarray!r} that does not fill its {item_bytes}-byte items")
    if names is not None or fields is not None:
        if not (isinstance(names, tuple) and isinstance(fields, dict) and set(names) <= set(fields)):
            raise _Refused("a structured dtype state whose field names and fields do not match")
        for name, spec in fields.items():
            dtype, offset = spec[:2] if isinstance(spec, tuple) and len(spec) in (2, 3) else (None, None)
            if not (isinstance(dtype, np.dtype) and isinstance(offset, int)
                    and 0 <= offset <= item_bytes - dtype.itemsize):
                raise _Refused(f"a structured dtype state whose field {name!r} lies outside its {item_bytes}-byte items")


class _ArrayUnpickler(pickle._Unpickler):  # noqa: SLF001 -- the Python one, whose BUILD can be checked
    """An unpickler whose only globals are those of :data:`_ADMITTED_GLOBALS`, and whose BUILD
    (``__setstate__``) reaches only plain numpy arrays and dtypes (:func:`_check_build`)."""

    dispatch = dict(pickle._Unpickler.dispatch)  # noqa: SLF001

    def load_build(self) -> None:
        _check_build(self.stack[-2], self.stack[-1])
        super().load_build()

    dispatch[pickle.BUILD[0]] = load_build

    def __init__(self, data: bytes, name: str):
        # latin-1 lets numpy arrays pickled by Python 2 load (their bytes are str there).
        super().__init__(io.BytesIO(data), encoding="latin1")
        self.name = name

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ADMITTED_GLOBALS[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"{self.name}: refused pickle global {module}.{name}: only numpy arrays are admitted "
                "(a pickle naming it could run code when loaded)"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"{self.name}: refused persistent id {pid!r}: only numpy arrays are admitted")


# The published pickles hold bare arrays (a published estimate at most a number or a short list
# of them), so these budgets on the lists, tuples and dicts around the arrays sit far above any
# legitimate file, and far below what a few hundred bytes of pickle could otherwise make the
# check, or ``np.asarray`` in :func:`load_pickled_array`, do through shared (memo) references.
MAX_PICKLE_DEPTH = 32
"""Containers nested in one another (an array in a list is 1 level)."""
MAX_PICKLE_ITEMS = 1_000_000
"""Items walked by the check: each container is walked once, each reference to it counts."""
MAX_PICKLE_ELEMENTS = 1 << 27
"""Array elements, scalars and containers counted at every reference: what ``np.asarray`` builds."""
MAX_PICKLE_BYTES = 1 << 30
"""Those elements at the widest item size among them: what ``np.asarray`` would allocate."""

# A Python number as numpy would hold it (complex128 at most).
_NUMBER_ITEMSIZE = 16
_END = object()


def _leaf_size(value: Any, name: str) -> tuple[int, int]:
    """(elements, item size in bytes) of anything but a container; refuses what is not admitted."""
    if isinstance(value, np.ndarray | np.generic):
        if value.dtype.hasobject:
            raise UnsafePickleError(f"{name}: refused an object array: only plain numpy arrays are admitted")
        return int(value.size), value.dtype.itemsize
    if isinstance(value, str):
        return 1, 4 * len(value)  # numpy holds text as UCS-4
    if isinstance(value, bytes):
        return 1, len(value)
    if value is None or isinstance(value, bool | int | float | complex):
        return 1, _NUMBER_ITEMSIZE
    raise UnsafePickleError(f"{name}: refused a {type(value).__name__}: only numpy arrays are admitted")


def _children(container: list | tuple | dict) -> Any:
    if isinstance(container, dict):
        return (part for pair in container.items() for part in pair)
    return iter(container)


def _check_plain(value: Any, name: str) -> None:
    """Refuse anything but numeric/string arrays, numpy scalars and plain data holding them.

    Walks without recursion, each container once however often it is referenced, and
    refuses containers nested beyond :data:`MAX_PICKLE_DEPTH`, more than
    :data:`MAX_PICKLE_ITEMS` items, a container holding itself, and containers whose
    contents counted at every reference exceed :data:`MAX_PICKLE_ELEMENTS` or
    :data:`MAX_PICKLE_BYTES` (a bare array is what the file holds, and is not limited).
    """
    if not isinstance(value, list | tuple | dict):
        _leaf_size(value, name)
        return
    expected = "only numpy arrays, in at most small lists, tuples or dicts, are admitted"
    # id -> (elements counted at every reference, widest item size, nesting levels); the
    # objects stay alive inside ``value``, so their ids are not reused during the walk.
    finished: dict[int, tuple[int, int, int]] = {}
    open_ids = {id(value)}
    # Per open container: the container, its children, and [elements, item size, levels below].
    stack: list[tuple[Any, Any, list[int]]] = [(value, _children(value), [1, 0, 0])]
    items = 0

    def add(total: list[int], elements: int, itemsize: int, levels: int) -> None:
        total[0] += elements
        total[1] = max(total[1], itemsize)
        total[2] = max(total[2], levels)
        if total[0] > MAX_PICKLE_ELEMENTS or total[0] * total[1] > MAX_PICKLE_BYTES:
            raise UnsafePickleError(
                f"{name}: refused containers holding over {MAX_PICKLE_ELEMENTS} elements or "
                f"{MAX_PICKLE_BYTES} bytes counted at every (shared) reference: {expected}"
            )

    while stack:
        container, children, total = stack[-1]
        child = next(children, _END)
        if child is _END:
            stack.pop()
            open_ids.discard(id(container))
            done = (total[0], total[1], total[2] + 1)
            if done[2] > MAX_PICKLE_DEPTH:
                raise UnsafePickleError(f"{name}: refused containers nested over {MAX_PICKLE_DEPTH} deep: {expected}")
            finished[id(container)] = done
            if stack:
                add(stack[-1][2], *done)
            continue
        items += 1
        if items > MAX_PICKLE_ITEMS:
            raise UnsafePickleError(f"{name}: refused containers of over {MAX_PICKLE_ITEMS} items: {expected}")
        if not isinstance(child, list | tuple | dict):
            add(total, *_leaf_size(child, name), 0)
        elif id(child) in finished:
            add(total, *finished[id(child)])
        elif id(child) in open_ids:
            raise UnsafePickleError(f"{name}: refused a {type(child).__name__} that holds itself: {expected}")
        elif len(stack) >= MAX_PICKLE_DEPTH:
            raise UnsafePickleError(f"{name}: refused containers nested over {MAX_PICKLE_DEPTH} deep: {expected}")
        else:
            open_ids.add(id(child))
            stack.append((child, _children(child), [1, 0, 0]))


def safe_load_pickle(source: str | os.PathLike[str] | bytes, *, name: str | None = None) -> Any:
    """Unpickle ``source`` (a path, or the pickle's bytes) admitting numpy arrays and nothing else.

    The unpickler resolves only the globals a pickled numpy array, dtype or numpy
    scalar needs (numpy 2 and numpy 1 names); any other global (``os.system``,
    ``eval``, ``subprocess.Popen``, ...) is refused before it is imported or
    called, so nothing in the pickle runs. The result may be an array, a numpy
    scalar, or plain numbers, strings, lists, tuples and dicts of them; object
    arrays are refused.

    Parameters
    ----------
    source : path or bytes
        The pickle file, or its contents.
    name : str, optional
        What to call the pickle in errors (default: the path, or ``"<bytes>"``).

    Raises
    ------
    UnsafePickleError
        The pickle names a global other than the admitted ones, builds an object array,
        or builds lists, tuples or dicts around its arrays beyond the budgets of
        :func:`_check_plain` (nested too deep, too many items, holding themselves, or too
        large counted at every shared reference); the message names the file and what
        was refused.
    DatasetError
        The file cannot be read, or is not a complete, valid pickle.
    """
    if isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
        name = name or "<bytes>"
    else:
        name = name or str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as exc:
            raise DatasetError(f"{name}: cannot read pickle ({exc.strerror or exc})") from exc
    try:
        value = _ArrayUnpickler(data, name).load()
    except UnsafePickleError:
        raise
    except _Refused as exc:
        raise UnsafePickleError(f"{name}: refused {exc}: only numpy arrays are admitted") from None
    except Exception as exc:  # a damaged pickle fails in many ways; each is the same user error
        raise DatasetError(f"{name}: not a valid pickle of numpy arrays ({type(exc).__name__}: {exc})") from exc
    _check_plain(value, name)
    return value


def _shape_text(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("n" if size is None else str(size) for size in shape) + ("," if len(shape) == 1 else "") + ")"


def array_from_pickle(value: Any, path: str | os.PathLike[str]) -> np.ndarray:
    """``np.asarray(value)``; DatasetError naming ``path`` where it holds no array (ragged lists)."""
    try:
        return np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise DatasetError(f"{path}: expected an array, got a {type(value).__name__} that makes none ({exc})") from None


def load_pickled_array(
    path: str | os.PathLike[str], *, ndim: int | None = None, shape: tuple[int | None, ...] | None = None,
    what: str = "",
) -> np.ndarray:
    """A numeric array from a pickle read with :func:`safe_load_pickle` (dtype kept as stored).

    Parameters
    ----------
    path : path
        The pickle.
    ndim : int, optional
        Required number of dimensions.
    shape : tuple of int or None, optional
        Required shape; a None entry is any size >= 1 (shown as ``n``).
    what : str
        What the array holds, for the shape error (e.g. ``"the published 250x350 images"``).

    Raises
    ------
    DatasetError
        The pickle is unsafe or damaged, does not hold an integer or float array (a bool
        array is not a measurement), holds non-finite values, or has another number of
        dimensions or shape. The message names the file and its dtype and shape.
    """
    value = array_from_pickle(safe_load_pickle(path), path)
    if value.dtype.kind not in "iuf":
        raise DatasetError(f"{path}: expected a numeric array (integer or float), got dtype {value.dtype}")
    if ndim is not None and value.ndim != ndim:
        raise DatasetError(f"{path}: expected a {ndim}-D array, got {value.dtype} shape {value.shape}")
    if shape is not None and (value.ndim != len(shape) or any(
            size == 0 or (want is not None and size != want) for size, want in zip(value.shape, shape, strict=True))):
        detail = f" ({what})" if what else ""
        raise DatasetError(f"{path}: expected shape {_shape_text(shape)}{detail}, got {value.dtype} {value.shape}")
    if value.dtype.itemsize > 8:
        # A long double may hold values no float64 can: they would turn infinite in the cast.
        with np.errstate(over="ignore"):
            if not np.all(np.isfinite(value.astype(np.float64))):
                raise DatasetError(f"{path}: {value.dtype} values beyond the float64 range (or NaN or infinite)")
    if not np.all(np.isfinite(value)):
        raise DatasetError(f"{path}: {np.count_nonzero(~np.isfinite(value))} values are NaN or infinite")
    return value


# A tared force reading out of contact sits a little either side of zero (noise, drift); a
# force below -1 N is a sign or tare error, not noise.
FORCE_TOLERANCE_N = 1.0
# A gripper's width reading may overshoot its nominal maximum a little when fully open.
WIDTH_SLACK_M = 0.005


def check_forces(path: str | os.PathLike[str], force_n: np.ndarray) -> None:
    """Refuse forces (N) that are not >= -:data:`FORCE_TOLERANCE_N`; the message names the file."""
    low = float(np.min(force_n)) if force_n.size else 0.0
    if low < -FORCE_TOLERANCE_N:
        raise DatasetError(
            f"{path}: forces must be >= 0 N (to a {FORCE_TOLERANCE_N:g} N tolerance for load-cell noise), "
            f"got {np.count_nonzero(force_n < -FORCE_TOLERANCE_N)} below, the lowest {low:.4g} N (a sign or tare error?)"
        )


def check_widths(path: str | os.PathLike[str], width_m: np.ndarray, max_width_m: float) -> None:
    """Refuse widths (m) outside 0 to ``max_width_m`` + :data:`WIDTH_SLACK_M`; the message names the file."""
    if not width_m.size:
        return
    low, high = float(np.min(width_m)), float(np.max(width_m))
    limit = max_width_m + WIDTH_SLACK_M
    if low < 0 or high > limit:
        # A width of tens "m" is a width in mm: no gripper opens a metre.
        hint = "; not in metres?" if high >= 1.0 else ""
        raise DatasetError(
            f"{path}: widths must lie within 0 to {limit:.4g} m (gripper.max_width_m {max_width_m:g} m "
            f"+ {WIDTH_SLACK_M:g} m), got {low:.4g} to {high:.4g}{hint}"
        )


# --------------------------------------------------------------------------- layout folders


def layout_index(folder: Path, key: str) -> int:
    # No leading zero: grasp=01 beside grasp=1 would be two records of one grasp index.
    match = re.fullmatch(rf"{key}=(0|[1-9]\d*)", folder.name)
    if match is None:
        raise DatasetError(f"{folder}: expected a folder named {key}=<integer> (no leading zero)")
    return int(match.group(1))


def layout_member(folder: Path, name: str) -> Path:
    path = folder / name
    if not path.is_file():
        raise DatasetError(f"{path}: missing (the layout needs it)")
    return path


def find_layout_folders(root: Path, pattern: str, what: str) -> list[Path]:
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory")
    folders = sorted(p for p in root.glob(pattern) if p.is_dir())
    if not folders:
        raise DatasetError(f"{root}: no {what} folders: not the expected layout")
    return folders
