"""Published-dataset pickles: the state (BUILD) numpy applies to arrays and dtypes, the edges of the
checks on arrays, forces, widths and layout folders."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.pickles import write_pickle

import teleop.system.dataset_files as dataset_files
from teleop.errors import DatasetError, UnsafePickleError
from teleop.system.dataset_files import (
    check_forces,
    check_widths,
    find_layout_folders,
    layout_index,
    layout_member,
    load_pickled_array,
    safe_load_pickle,
)


def body(value) -> bytes:
    """The opcodes that push ``value`` (a protocol-2 pickle without its PROTO and STOP)."""
    return pickle.dumps(value, protocol=2)[2:-1]


MEMO = (100_000).to_bytes(4, "little")  # a memo slot that ``body`` never uses
RECONSTRUCT = pickle.GLOBAL + b"numpy.core.multiarray\n_reconstruct\n"
NDARRAY = pickle.GLOBAL + b"numpy\nndarray\n"


def placeholder(subtype: bytes = NDARRAY) -> bytes:
    """numpy's empty array placeholder: _reconstruct(subtype, (0,), b"b")."""
    return RECONSTRUCT + subtype + body((0,)) + body(b"b") + pickle.TUPLE3 + pickle.REDUCE


def object_array_short_list(n: int) -> bytes:
    """An object array of shape (n,) whose state lists one item: numpy fills n from the list unchecked."""
    state = pickle.MARK + body(1) + body((n,)) + pickle.GLOBAL + b"numpy\ndtype\n" + body(("O8", False, True))
    state += pickle.REDUCE + pickle.NEWFALSE + body([1.0]) + pickle.TUPLE
    return b"\x80\x02" + placeholder() + state + pickle.BUILD + pickle.STOP


def poisoned_dtype_array(n: int) -> bytes:
    """A plain void dtype given object flags by its state, then an array of it filled from a short list."""
    out = b"\x80\x02" + pickle.GLOBAL + b"numpy\ndtype\n" + body(("V8", False, True)) + pickle.REDUCE
    out += pickle.LONG_BINPUT + MEMO + body((3, "|", None, None, None, 8, 1, 63)) + pickle.BUILD + pickle.POP
    out += placeholder() + pickle.MARK + body(1) + body((n,)) + pickle.LONG_BINGET + MEMO + pickle.NEWFALSE
    return out + body([1.0]) + pickle.TUPLE + pickle.BUILD + pickle.STOP


# safe_load_pickle(argv[1]) in a child process: a pickle that crashes numpy fails the test
# instead of the suite.
_CHILD_LOAD = """
import sys
from teleop.errors import DatasetError
from teleop.system.dataset_files import safe_load_pickle
try:
    safe_load_pickle(sys.argv[1])
except DatasetError as exc:
    print(type(exc).__name__, exc)
else:
    print("loaded")
"""


@pytest.mark.parametrize(
    ("build", "refused"),
    [(lambda: object_array_short_list(1000), "object array"), (lambda: poisoned_dtype_array(1000), "object flags")],
    ids=["object-dtype", "void-dtype-with-object-flags"],
)
def test_an_object_array_is_refused_before_numpy_fills_it(tmp_path, build, refused):
    path = tmp_path / "forces.pkl"
    path.write_bytes(build())
    done = subprocess.run([sys.executable, "-c", _CHILD_LOAD, str(path)], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parents[3], env={**os.environ})
    assert done.returncode == 0, f"the load crashed (status {done.returncode}): {done.stderr[-2000:]}"
    assert done.stdout.startswith(f"UnsafePickleError {path}: refused") and refused in done.stdout, done.stdout


def test_a_structured_dtype_whose_field_lies_outside_its_items_is_refused(tmp_path):
    # Its state sets a field offset numpy never checks: np.asarray of a list of such arrays crashes.
    state = list(np.dtype([("a", "<f8")]).__reduce__()[2])
    state[4] = {"a": (np.dtype("<f8"), 1 << 28)}
    poisoned = np.dtype("V8")
    poisoned.__setstate__(tuple(state))
    path = tmp_path / "forces.pkl"
    path.write_bytes(pickle.dumps([np.zeros(1000, "V8").view(poisoned)] * 2, protocol=2))
    done = subprocess.run([sys.executable, "-c", _CHILD_LOAD, str(path)], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parents[3], env={**os.environ})
    refusal = f"UnsafePickleError {path}: refused a structured dtype state whose field 'a' lies outside its 8-byte items"
    assert done.stdout.startswith(refusal), done.stdout + done.stderr[-2000:]


def test_a_subarray_dtype_state_bigger_than_its_items_is_refused():
    out = b"\x80\x02" + pickle.GLOBAL + b"numpy\ndtype\n" + body(("V24", False, True)) + pickle.REDUCE
    out += body((3, "|", (np.dtype("<f8"), (1 << 20,)), None, None, 24, 8, 0)) + pickle.BUILD + pickle.STOP
    with pytest.raises(UnsafePickleError, match="subarray dtype state .* does not fill its 24-byte items"):
        safe_load_pickle(out, name="dtype.pkl")


@pytest.mark.parametrize("value", [np.zeros(2, dtype=[("force", "<f8"), ("frame", "<i4", (3,))]),
                                   np.zeros(2, dtype=np.dtype({"names": ["a"], "formats": ["<f4"], "offsets": [4],
                                                               "itemsize": 12})),
                                   np.zeros(2, dtype=[(("title", "t"), "<f8")])], ids=["nested", "padded", "titled"])
def test_structured_and_subarray_dtypes_within_their_items_load(value):
    loaded = safe_load_pickle(pickle.dumps(value, protocol=2))
    assert loaded.dtype == value.dtype and np.array_equal(loaded, value)


def test_a_dtype_state_with_object_flags_is_refused_alone():
    out = b"\x80\x02" + pickle.GLOBAL + b"numpy\ndtype\n" + body(("V8", False, True)) + pickle.REDUCE
    out += body((3, "|", None, None, None, 8, 1, 1)) + pickle.BUILD + pickle.STOP
    with pytest.raises(UnsafePickleError, match="object flags"):
        safe_load_pickle(out, name="dtype.pkl")


def test_a_state_for_anything_but_an_array_or_dtype_is_refused_and_changes_nothing():
    # BUILD with a slot state would set an attribute on the unpickler's own stand-in for ndarray.
    data = b"\x80\x02" + NDARRAY + body((None, {"audit_marker": 1})) + pickle.BUILD + pickle.STOP
    with pytest.raises(UnsafePickleError, match="ndarray.pkl: refused"):
        safe_load_pickle(data, name="ndarray.pkl")
    assert not hasattr(dataset_files._PickledNdarrayType, "audit_marker")


def test_reconstruct_of_another_type_than_ndarray_is_refused():
    data = b"\x80\x02" + placeholder(pickle.GLOBAL + b"numpy\ndtype\n") + pickle.STOP
    with pytest.raises(UnsafePickleError, match="_reconstruct of"):
        safe_load_pickle(data, name="sub.pkl")


def test_a_persistent_id_is_refused_naming_the_file():
    with pytest.raises(UnsafePickleError, match=r"pid\.pkl: refused persistent id 'x'"):
        safe_load_pickle(b"Px\n.", name="pid.pkl")


@pytest.mark.parametrize("codec", ["latin-1", "ISO-8859-1", "L1", "latin_1"])
def test_latin1_by_any_of_its_names_is_admitted(codec):
    data = pickle.GLOBAL + b"_codecs\nencode\n" + body(("\xe9", codec)) + pickle.REDUCE + pickle.STOP
    assert safe_load_pickle(data) == b"\xe9"


def test_python2_text_array_bytes_are_read_as_latin1():
    # Python 2 wrote an array's bytes as a str (SHORT_BINSTRING): read as latin-1, numpy takes them back.
    array = np.array([1.0, -2.5])
    raw = array.tobytes()
    dtype = pickle.GLOBAL + b"numpy\ndtype\n" + body(("f8", False, True)) + pickle.REDUCE
    state = pickle.MARK + body(1) + body((2,)) + dtype + pickle.NEWFALSE + b"U" + bytes([len(raw)]) + raw
    data = b"\x80\x02" + placeholder() + state + pickle.TUPLE + pickle.BUILD + pickle.STOP
    assert np.array_equal(safe_load_pickle(data), array)


def test_a_dict_key_is_checked_like_a_value():
    with pytest.raises(UnsafePickleError, match="refused a"):
        safe_load_pickle(b"\x80\x02}" + NDARRAY + body(1) + b"s.", name="key.pkl")


def test_none_is_admitted_but_a_set_is_not():
    assert safe_load_pickle(pickle.dumps(None)) is None
    assert safe_load_pickle(pickle.dumps([None, True])) == [None, True]
    with pytest.raises(UnsafePickleError, match="refused a set"):
        safe_load_pickle(pickle.dumps({1.0}), name="set.pkl")


def test_bytes_elements_count_towards_the_byte_budget(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_BYTES", 1000)
    with pytest.raises(UnsafePickleError, match="every \\(shared\\) reference"):
        safe_load_pickle(pickle.dumps([b"x" * 600, b"y" * 600]))
    safe_load_pickle(pickle.dumps([b"x" * 300, b"y" * 300]))  # 3 elements of 300 bytes: within budget


def test_the_widest_item_sets_the_byte_budget(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_BYTES", 1000)
    # 100 numbers of 16 bytes then one short text: 101 elements at 16 bytes each, over 1000.
    with pytest.raises(UnsafePickleError, match="every \\(shared\\) reference"):
        safe_load_pickle(pickle.dumps([1.0] * 100 + ["a"]))


def test_the_element_budget_alone_refuses(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_ELEMENTS", 10)
    with pytest.raises(UnsafePickleError, match="over 10 elements"):
        safe_load_pickle(pickle.dumps([0] * 11))
    assert safe_load_pickle(pickle.dumps([0] * 9)) == [0] * 9


def test_the_item_budget_refuses(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_ITEMS", 5)
    with pytest.raises(UnsafePickleError, match="over 5 items"):
        safe_load_pickle(pickle.dumps([0] * 6), name="many.pkl")


def test_shared_containers_count_at_every_reference(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_ELEMENTS", 50)
    inner = [0] * 10
    assert safe_load_pickle(pickle.dumps([inner] * 4))[3] == inner  # 4 x 11 elements
    with pytest.raises(UnsafePickleError, match="over 50 elements"):
        safe_load_pickle(pickle.dumps([inner] * 5))


def test_a_list_met_twice_is_not_taken_for_one_holding_itself():
    inner = [1.0]
    assert safe_load_pickle(pickle.dumps([inner, (inner,)])) == [[1.0], ([1.0],)]


def test_33_nested_lists_are_refused_as_too_deep():
    with pytest.raises(UnsafePickleError, match="nested over 32 deep"):
        safe_load_pickle(b"\x80\x02" + b"(" * 33 + b"l" * 33 + b".", name="deep.pkl")
    value = safe_load_pickle(b"\x80\x02" + b"(" * 32 + b"l" * 32 + b".")
    depth = 0
    while isinstance(value, list):
        value, depth = (value[0] if value else None), depth + 1
    assert depth == 32


def test_a_bare_object_leaf_is_refused():
    with pytest.raises(UnsafePickleError, match="refused a"):
        safe_load_pickle(b"\x80\x02" + NDARRAY + b".", name="type.pkl")


def test_an_unsafe_pickle_stays_an_unsafe_pickle_error(tmp_path):
    path = tmp_path / "x.pkl"
    path.write_bytes(b"cos\nsystem\n(S'true'\ntR.")
    with pytest.raises(UnsafePickleError):
        load_pickled_array(path)


@pytest.mark.parametrize("value", [np.array([True, False]), np.array([1 + 2j]), np.array(["a"])])
def test_a_non_numeric_array_is_refused(tmp_path, value):
    path = tmp_path / "x.pkl"
    write_pickle(path, value)
    with pytest.raises(DatasetError, match="expected a numeric array"):
        load_pickled_array(path)


def test_shape_checks_every_dimension_and_refuses_an_empty_one(tmp_path):
    path = tmp_path / "x.pkl"
    write_pickle(path, np.zeros((0, 3)))
    with pytest.raises(DatasetError, match=r"expected shape \(n, 3\) \(forces\), got float64 \(0, 3\)"):
        load_pickled_array(path, shape=(None, 3), what="forces")
    write_pickle(path, np.zeros((2, 3, 1)))
    with pytest.raises(DatasetError, match=r"expected shape \(n, 3\)"):
        load_pickled_array(path, shape=(None, 3))
    write_pickle(path, np.zeros(4))
    with pytest.raises(DatasetError, match=r"expected shape \(n, 3\)"):
        load_pickled_array(path, shape=(None, 3))
    write_pickle(path, np.zeros((2, 3)))
    assert load_pickled_array(path, ndim=2, shape=(None, 3)).shape == (2, 3)


@pytest.mark.skipif(np.finfo(np.longdouble).max <= np.finfo(np.float64).max, reason="long double is float64 here")
def test_a_long_double_beyond_the_float64_range_is_refused(tmp_path):
    path = tmp_path / "x.pkl"
    write_pickle(path, np.array([1.0, np.finfo(np.longdouble).max], dtype=np.longdouble))
    with pytest.raises(DatasetError, match="beyond the float64 range"):
        load_pickled_array(path)


def test_widths_just_past_the_slack_are_refused_and_at_it_kept():
    check_widths("w.pkl", np.array([0.0, 0.085]), 0.08)
    with pytest.raises(DatasetError, match=r"w\.pkl: widths must lie within 0 to 0\.085 m"):
        check_widths("w.pkl", np.array([0.0, 0.0851]), 0.08)
    with pytest.raises(DatasetError, match="got -1e-05 to"):
        check_widths("w.pkl", np.array([-1e-5, 0.02]), 0.08)
    with pytest.raises(DatasetError, match="not in metres"):
        check_widths("w.pkl", np.array([30.0]), 0.08)
    check_widths("w.pkl", np.array([]), 0.08)


def test_layout_folders_are_named_key_equals_integer_in_full(tmp_path):
    assert layout_index(tmp_path / "grasp=12", "grasp") == 12 and layout_index(tmp_path / "grasp=0", "grasp") == 0
    for name in ("grasp=12b", "grasp=", "xgrasp=1", "grasp=-1", "grasp=01", "grasp=00"):
        with pytest.raises(DatasetError, match="expected a folder named grasp=<integer>"):
            layout_index(tmp_path / name, "grasp")


def test_a_layout_member_must_be_a_file(tmp_path):
    (tmp_path / "forces.pkl").mkdir()
    with pytest.raises(DatasetError, match=r"forces\.pkl: missing"):
        layout_member(tmp_path, "forces.pkl")


def test_layout_folders_are_folders_only_and_the_root_must_be_one(tmp_path):
    (tmp_path / "apple").mkdir()
    (tmp_path / "apple" / "grasp=0").write_text("not a folder")
    with pytest.raises(DatasetError, match="no <object>/grasp=<i> folders"):
        find_layout_folders(tmp_path, "*/grasp=*", "<object>/grasp=<i>")
    with pytest.raises(DatasetError, match="not a directory"):
        find_layout_folders(tmp_path / "absent", "*/grasp=*", "<object>/grasp=<i>")
    with pytest.raises(DatasetError, match="not a directory"):
        find_layout_folders(tmp_path / "apple" / "grasp=0", "*", "x")


def test_a_narrow_item_after_a_wide_one_keeps_the_wide_item_size(monkeypatch):
    monkeypatch.setattr(dataset_files, "MAX_PICKLE_BYTES", 1000)
    # A 100-character text (400 bytes as numpy holds it) then two numbers: 3 elements of 400 bytes.
    with pytest.raises(UnsafePickleError, match="every \\(shared\\) reference"):
        safe_load_pickle(pickle.dumps(["x" * 100, 0, 0]))


def nested(levels: int, innermost=None) -> list:
    value: list = [] if innermost is None else [innermost]
    for _ in range(levels - 1):
        value = [value]
    return value


def test_a_shared_chain_met_again_deeper_counts_its_depth():
    # A chain of 31 lists, then the same chain inside one more list: [A, [A]] is 33 deep,
    # though no walk down it ever holds more than 32 lists open.
    chain = nested(31)
    with pytest.raises(UnsafePickleError, match="nested over 32 deep"):
        safe_load_pickle(pickle.dumps([chain, [chain]]), name="shared.pkl")
    assert len(safe_load_pickle(pickle.dumps([chain, chain]))) == 2  # 32 deep


def test_too_deep_is_refused_before_what_lies_deeper_is_looked_at():
    with pytest.raises(UnsafePickleError, match="nested over 32 deep"):
        safe_load_pickle(pickle.dumps(nested(33, innermost={1.0})), name="deep.pkl")


def test_a_force_just_past_the_noise_tolerance_is_refused():
    with pytest.raises(DatasetError, match=r"f\.pkl: forces must be >= 0 N .*got 1 below, the lowest -1\.2 N"):
        check_forces("f.pkl", np.array([0.0, -1.2, 3.0]))
    check_forces("f.pkl", np.array([]))  # nothing to check
