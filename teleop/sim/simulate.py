"""Simulated grasp records: each grasp's file name and random stream.

Each grasp is drawn from its own random stream (:func:`grasp_rng`), seeded by (run seed,
object name, grasp index), so a seed gives the same records whatever the number of worker
processes and whichever objects are simulated beside it. With a randomized rig
(:mod:`teleop.sim.rig`) the rig is drawn from that stream before anything else. Drawn
contact mechanics (:mod:`teleop.sim.mechanics`) come from a stream of their own
(:func:`mechanics_rng`, fixed by the same three), so that with and without them a grasp
has the same rig, pose, operator and noise. Each grasp is written to
``<object>_g<index>.grasp`` (:func:`grasp_filename`); objects whose names give the same file
name are refused (:func:`check_filenames`). ``teleop simulate`` simulates and writes them.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable

import numpy as np

from teleop.catalogue import ObjectSpec
from teleop.errors import SettingsError
from teleop.record import safe_name


def grasp_filename(obj: ObjectSpec, index: int) -> str:
    """``<object>_g<index>.grasp`` with the name made safe for any file system."""
    return f"{safe_name(obj.name)}_g{index:03d}.grasp"


def check_filenames(objects: Iterable[ObjectSpec], where: str) -> None:
    """Refuse objects whose records would share a file name (:func:`grasp_filename`), which one
    would overwrite the other's; names differing only in case count as one, as on case-insensitive
    file systems."""
    seen: dict[str, str] = {}
    for obj in objects:
        key = safe_name(obj.name).casefold()
        if key in seen:
            raise SettingsError(f"{where}: objects {seen[key]!r} and {obj.name!r} would both be written to "
                                f"{safe_name(obj.name)}_g<index>.grasp: rename one (file names keep only "
                                "letters, digits, '.', '_' and '-')")
        seen[key] = obj.name


def grasp_rng(seed: int, obj: ObjectSpec, index: int) -> np.random.Generator:
    """The random stream of one grasp: fixed by the run seed, the object's name and the grasp index."""
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(obj.name.encode()), index]))


# Tags the contact mechanics' stream apart from the grasp's (whose children the cameras spawn).
_MECHANICS_STREAM = zlib.crc32(b"contact mechanics")


def mechanics_rng(seed: int, obj: ObjectSpec, index: int) -> np.random.Generator:
    """The random stream of one grasp's contact mechanics: fixed by the run seed, the object's name and
    the grasp index, and independent of :func:`grasp_rng`'s."""
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(obj.name.encode()), index,
                                                         _MECHANICS_STREAM]))
