"""Pickles for tests of the published-dataset import."""

from __future__ import annotations

import pickle
from pathlib import Path


def write_pickle(path: Path, value, protocol: int = pickle.DEFAULT_PROTOCOL) -> None:
    path.write_bytes(pickle.dumps(value, protocol=protocol))


class RunsCode:
    """A pickle payload that would call ``func(*args)`` if anything executed it."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args
