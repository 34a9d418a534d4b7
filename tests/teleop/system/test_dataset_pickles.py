"""Published-dataset pickles: the safe unpickler rebuilds numpy arrays and refuses everything else,
within budgets of depth and size."""

from __future__ import annotations

import builtins
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.pickles import RunsCode, write_pickle

from teleop.errors import DatasetError, UnsafePickleError
from teleop.system.dataset_files import (
    FORCE_TOLERANCE_N,
    check_forces,
    load_pickled_array,
    safe_load_pickle,
)


@pytest.mark.parametrize("protocol", range(pickle.HIGHEST_PROTOCOL + 1))
def test_safe_load_pickle_rebuilds_numpy_arrays_exactly(protocol):
    values = [
        np.arange(12, dtype=np.float32).reshape(3, 4),
        np.asfortranarray(np.linspace(0, 1, 6).reshape(2, 3)),
        np.zeros(2, dtype=[("force", "<f8"), ("frame", "<i4")]),
        np.array([True, False]),
        np.array(["abc", "de"]),
        np.arange(5, dtype=">i8"),
    ]
    for value in values:
        data = pickle.dumps(value, protocol=protocol)
        loaded, plain = safe_load_pickle(data), pickle.loads(data)
        assert type(loaded) is np.ndarray
        # What the unrestricted unpickler builds (numpy itself drops a big-endian order below
        # protocol 5), and the same values as pickled.
        assert loaded.dtype == plain.dtype and loaded.shape == value.shape
        assert np.array_equal(loaded, value)
        assert loaded.flags.f_contiguous == value.flags.f_contiguous
    scalars = [np.float64(2.5e6), np.int64(-3), np.float32(0.25), 3.0, [np.float64(1.0), 2]]
    for value in scalars:
        loaded = safe_load_pickle(pickle.dumps(value, protocol=protocol))
        assert type(loaded) is type(value) and loaded == value


def test_safe_load_pickle_reads_numpy1_names(tmp_path):
    # numpy 1.x wrote numpy.core.multiarray / numpy.core.numeric; numpy 2 renamed them numpy._core.
    data = pickle.dumps(np.arange(4.0), protocol=2)
    assert b"numpy._core.multiarray" in data
    path = tmp_path / "old.pkl"
    path.write_bytes(data.replace(b"numpy._core.multiarray", b"numpy.core.multiarray"))
    assert np.array_equal(safe_load_pickle(path), np.arange(4.0))
    scalar = pickle.dumps(np.float64(7.5), protocol=2).replace(b"numpy._core", b"numpy.core")
    assert safe_load_pickle(scalar) == 7.5
    # numpy 1.x protocol 5: numpy.core.numeric._frombuffer(buffer, dtype, shape, order).
    array = np.arange(6, dtype=np.int16).reshape(2, 3)
    arguments = pickle.dumps((array.tobytes(), array.dtype, array.shape, "C"), protocol=2)
    frombuffer = b"\x80\x02cnumpy.core.numeric\n_frombuffer\n" + arguments[2:-1] + b"R."
    assert np.array_equal(safe_load_pickle(frombuffer), array)


@pytest.mark.parametrize(
    ("payload", "refused"),
    [
        (lambda m: RunsCode(os.system, f"touch {m}"), "system"),
        (lambda m: RunsCode(eval, f"open({str(m)!r}, 'w').close()"), "builtins.eval"),
        (lambda m: RunsCode(exec, f"open({str(m)!r}, 'w').close()"), "builtins.exec"),
        (lambda m: RunsCode(subprocess.Popen, ["touch", str(m)]), "subprocess.Popen"),
        (lambda m: RunsCode(builtins.open, str(m), "w"), "open"),
        # Hidden behind a legitimate array: refused all the same.
        (lambda m: [np.arange(3.0), RunsCode(os.system, f"touch {m}")], "system"),
    ],
)
def test_malicious_pickle_is_refused_and_runs_nothing(tmp_path, payload, refused):
    marker = tmp_path / "pwned"
    path = tmp_path / "object_forces.pkl"
    write_pickle(path, payload(marker))
    with pytest.raises(UnsafePickleError) as info:
        safe_load_pickle(path)
    message = str(info.value)
    assert str(path) in message and refused in message
    assert not marker.exists()


def test_refused_globals_are_never_imported(tmp_path):
    # GLOBAL opcode naming a module that does not exist: refused by name, not by a failed import.
    data = b"cno_such_module_xyz\nrun\n(tR."
    with pytest.raises(UnsafePickleError, match=r"no_such_module_xyz\.run"):
        safe_load_pickle(data, name="crafted.pkl")
    # numpy functions other than the array-rebuilding ones are refused too.
    for global_name in (b"numpy\nload\n", b"numpy.testing._private.utils\nrunstring\n"):
        with pytest.raises(UnsafePickleError, match="crafted.pkl"):
            safe_load_pickle(b"c" + global_name + b"(tR.", name="crafted.pkl")


def test_admitted_globals_cannot_be_misused():
    # ndarray(shape) called directly would allocate whatever the pickle asks for.
    with pytest.raises(UnsafePickleError, match="numpy.ndarray"):
        safe_load_pickle(b"cnumpy\nndarray\n(I1000000000000\ntR.")
    # _reconstruct only ever builds numpy's empty placeholder, filled from the pickled state.
    huge = pickle.dumps(np.arange(3.0), protocol=2).replace(b"K\x00\x85", b"J\x00\xe1\xf5\x05\x85")
    with pytest.raises(UnsafePickleError, match="shape"):
        safe_load_pickle(huge)
    # _codecs.encode with any codec but latin-1.
    import codecs

    with pytest.raises(UnsafePickleError, match="rot13"):
        safe_load_pickle(pickle.dumps(RunsCode(codecs.encode, "abc", "rot13")))
    # An object array could carry arbitrary Python objects.
    with pytest.raises(UnsafePickleError, match="object array"):
        safe_load_pickle(pickle.dumps(np.array([1, "a"], dtype=object)))


def test_damaged_or_missing_pickles_raise_dataset_errors(tmp_path):
    path = tmp_path / "forces.pkl"
    path.write_bytes(pickle.dumps(np.arange(100.0))[:-20])
    with pytest.raises(DatasetError, match=r"forces\.pkl: not a valid pickle"):
        safe_load_pickle(path)
    with pytest.raises(DatasetError, match="cannot read"):
        safe_load_pickle(tmp_path / "absent.pkl")
    write_pickle(path, {"force": 1.0})
    with pytest.raises(DatasetError, match="numeric array"):
        load_pickled_array(path)
    write_pickle(path, np.array([1.0, np.nan]))
    with pytest.raises(DatasetError, match="NaN or infinite"):
        load_pickled_array(path)
    write_pickle(path, np.zeros((2, 2)))
    with pytest.raises(DatasetError, match="1-D"):
        load_pickled_array(path, ndim=1)


def shared_list_pickle(depth: int, fan: int) -> bytes:
    """A protocol-2 pickle of ``depth`` nested lists, each holding ``fan`` memo references to
    the one below: a few hundred bytes that stand for fan**depth lists if walked as a tree."""
    out = bytearray(b"\x80\x02]q\x00")  # EMPTY_LIST, BINPUT 0
    for level in range(1, depth + 1):
        # EMPTY_LIST MARK (BINGET level-1)*fan APPENDS BINPUT level POP
        out += b"](" + (b"h" + bytes([level - 1])) * fan + b"eq" + bytes([level]) + b"0"
    return bytes(out + b"h" + bytes([depth]) + b".")


# load_pickled_array(argv[1]) in a child process limited to 2 GiB of address space, so that
# a pickle that walks or allocates without end fails the test instead of hanging the suite.
_GUARDED_LOAD = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
from teleop.errors import DatasetError
from teleop.system.dataset_files import load_pickled_array
try:
    load_pickled_array(sys.argv[1])
except DatasetError as exc:
    print("refused:", exc)
else:
    print("loaded")
"""


@pytest.mark.parametrize(
    ("build", "refused"),
    [
        # 40 levels of two shared references: 2**40 lists, 408 bytes.
        (lambda: shared_list_pickle(40, 2), "nested over 32 deep"),
        # Within the depth budget, but 2**31 lists counted at every reference.
        (lambda: shared_list_pickle(30, 2), "every (shared) reference"),
        # One 1 MiB array referenced 2048 times: np.asarray would build 2 GiB.
        (lambda: pickle.dumps([np.zeros(1 << 17)] * 2048, protocol=4), "every (shared) reference"),
    ],
    ids=["dag-40-deep", "dag-2**31-lists", "shared-array"],
)
def test_pickle_of_shared_references_is_refused_quickly(tmp_path, build, refused):
    path = tmp_path / "forces.pkl"
    path.write_bytes(build())
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    try:
        done = subprocess.run([sys.executable, "-c", _GUARDED_LOAD, str(path)], capture_output=True, text=True,
                              timeout=20, cwd=Path(__file__).resolve().parents[3], env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{path.name} ({path.stat().st_size} bytes) still loading after 20 s", pytrace=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(f"refused: {path}: refused") and refused in done.stdout, done.stdout


@pytest.mark.slow
def test_deep_huge_or_self_holding_containers_are_refused_by_name():
    # 200,000 nested lists (400 kB): a clear error, not a RecursionError.
    n = 200_000
    with pytest.raises(UnsafePickleError, match=r"deep\.pkl: refused containers nested over 32 deep"):
        safe_load_pickle(b"\x80\x02" + b"(" * n + b"l" * n + b".", name="deep.pkl")
    # A list or dict that holds itself (through the memo).
    with pytest.raises(UnsafePickleError, match=r"loop\.pkl: refused a list that holds itself"):
        safe_load_pickle(b"\x80\x02]q\x00h\x00a.", name="loop.pkl")
    with pytest.raises(UnsafePickleError, match=r"loop\.pkl: refused a dict that holds itself"):
        safe_load_pickle(b"\x80\x02}q\x00K\x01h\x00s.", name="loop.pkl")
    # Over a million items.
    with pytest.raises(UnsafePickleError, match=r"many\.pkl: refused containers of over 1000000 items"):
        safe_load_pickle(pickle.dumps([None] * 1_000_001), name="many.pkl")


def test_shared_and_nested_arrays_within_the_budgets_still_load(tmp_path):
    array = np.arange(6.0)
    value = safe_load_pickle(pickle.dumps({"a": array, "b": (array, [array])}))
    assert np.array_equal(value["b"][1][0], array) and value["a"] is value["b"][0]
    shared = safe_load_pickle(shared_list_pickle(20, 2))  # 2**21 lists as a tree, 21 levels
    assert len(shared) == 2 and shared[0] is shared[1]
    deepest = safe_load_pickle(shared_list_pickle(31, 1))  # 32 levels, the most admitted
    expected: list = []
    for _ in range(31):
        expected = [expected]
    assert deepest == expected
    path = tmp_path / "forces.pkl"
    write_pickle(path, [array] * 3)
    assert load_pickled_array(path, shape=(3, 6)).sum() == 3 * array.sum()


def test_a_force_a_little_past_the_noise_tolerance_is_refused():
    # -2 N is a sign or tare error, not load-cell noise
    with pytest.raises(DatasetError, match=r"got 1 below, the lowest -2 N"):
        check_forces("forces.pkl", np.array([0.3, -2.0, 5.0, 11.0]))


def test_forces_within_the_noise_tolerance_are_kept():
    check_forces("forces.pkl", np.array([-FORCE_TOLERANCE_N, -0.4, 0.0, 12.0]))  # no error
