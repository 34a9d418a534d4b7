"""Whether a device family's contract suite runs every backend its name table has."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def param_names(params: Iterable[Any]) -> set[str]:
    """The values of a fixture's ``params``: plain values and ``pytest.param`` ones alike."""
    return {getattr(p, "values", (p,))[0] for p in params}


def assert_every_backend_covered(family: str, backends: Iterable[str], covered: Iterable[str], *,
                                 fixture: str, where: str) -> None:
    """Fail naming each of ``backends`` not in ``covered`` and the fixture to add it to.

    Parameters
    ----------
    family : str
        The device family, as the failure names it.
    backends : iterable of str
        The names in the family's ``BACKENDS`` table.
    covered : iterable of str
        The backends the contract suite's ``fixture`` runs the suite on.
    fixture, where : str
        The fixture's name and the file that defines it.
    """
    missing = sorted(set(backends) - set(covered))
    assert not missing, (f"{family} backend(s) {', '.join(map(repr, missing))} in BACKENDS never run the contract "
                         f"suite: add a parameter for each to the `{fixture}` fixture in {where}")
