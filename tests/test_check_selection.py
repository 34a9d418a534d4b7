"""`make check` runs without the train extra: the test modules that need torch to be imported are
exactly :data:`support.extras.TRAIN_MODULES` (marked train, not collected without torch)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from support.extras import TRAIN_MODULES, WITHOUT_TORCH

TESTS = Path(__file__).resolve().parent

# Imports every test module by path where torch cannot be imported; prints those that needed it.
_IMPORT_ALL = WITHOUT_TORCH + """
import importlib.util, json, pathlib
tests = pathlib.Path(sys.argv[1])
sys.path[:0] = [str(tests), str(tests.parent)]
needs = []
for path in sorted(tests.rglob("test_*.py")):
    name = "_t_" + "_".join(path.relative_to(tests).with_suffix("").parts)
    spec = importlib.util.spec_from_file_location(name, path)
    module = sys.modules[name] = importlib.util.module_from_spec(spec)  # as dataclasses look it up
    try:
        spec.loader.exec_module(module)
    except ModuleNotFoundError as exc:
        if (exc.name or "").partition(".")[0] != "torch":
            raise
        needs.append(path.relative_to(tests).as_posix())
print(json.dumps(needs))
"""


@pytest.mark.slow
def test_the_modules_marked_train_are_those_that_import_torch():
    done = subprocess.run([sys.executable, "-c", _IMPORT_ALL, str(TESTS)], capture_output=True, text=True,
                          timeout=300, cwd=TESTS.parent)
    assert done.returncode == 0, done.stderr
    assert set(json.loads(done.stdout.strip().splitlines()[-1])) == TRAIN_MODULES
