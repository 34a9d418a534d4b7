"""Simulated grasp records: each grasp's file name and random stream.

Each grasp is drawn from its own random stream (:func:`grasp_rng`), seeded by (run seed,
object name, grasp index), so a seed gives the same records whatever the number of worker
processes and whichever objects are simulated beside it. With a randomized rig
(:mod:`teleop.sim.rig`) the rig is drawn from that stream before anything else. Drawn
contact mechanics (:mod:`teleop.sim.mechanics`) come from a stream of their own
(:func:`mechanics_rng`, fixed by the same three), so that with and without them a grasp
has the same rig, pose, operator and noise. Each grasp is written to
``<object>_g<index>.grasp`` (:func:`grasp_filename`). ``teleop simulate`` simulates and
writes them.
"""

from __future__ import annotations

import re
import zlib

import numpy as np

from teleop.catalogue import ObjectSpec


def grasp_filename(obj: ObjectSpec, index: int) -> str:
    """``<object>_g<index>.grasp`` with the name made safe for any file system."""
    return f"{re.sub(r'[^A-Za-z0-9._-]+', '_', obj.name)}_g{index:03d}.grasp"


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
