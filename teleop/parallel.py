"""Work mapped over worker processes with a progress bar: simulation, dataset building, evaluation."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from multiprocessing import get_context
from types import FrameType
from typing import TypeVar

import cv2

from teleop.live import sigint_ignored
from teleop.progress import progress_bar

__all__ = ["progress_map"]

T = TypeVar("T")
R = TypeVar("R")


# Resolved in the parent, not in a forked worker: another thread may hold the loader's lock at fork time.
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None
_PR_SET_PDEATHSIG = 1
_working = False  # in a worker: inside a chunk's work


def _stop_worker(signum: int, frame: FrameType | None) -> None:
    """A worker's SIGTERM (from the parent stopping the pool, or from the kernel as the parent died):
    inside the work, KeyboardInterrupt, so that the work cleans up after itself (a record's temporary
    file removed) before :func:`_run_chunk` ends the process; elsewhere, the process ends at once."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second one (the parent's death after its stop) must not cut the clean-up short
    if _working:
        raise KeyboardInterrupt
    os._exit(128 + signum)


def _init_worker(parent: int, one_thread: bool) -> None:
    """In each worker, first: SIGTERM handled by :func:`_stop_worker` (a forked worker inherits the
    parent's handler, which would not end it), and SIGTERM from the kernel when the parent dies, even
    killed outright (Linux), so that no worker outlives it and works on for nobody."""
    signal.signal(signal.SIGTERM, _stop_worker)
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != parent:  # the parent died before that
        os._exit(128 + signal.SIGTERM)
    if one_thread:
        cv2.setNumThreads(1)  # one core per worker: OpenCV would otherwise spread over all of them


def _run_chunk(work: Callable[[T], R], chunk: list[T]) -> list[R]:
    global _working
    try:
        _working = True
        return [work(item) for item in chunk]
    except KeyboardInterrupt:
        # Only SIGTERM interrupts a worker (it ignores SIGINT): its work cleaned up; now it ends.
        os._exit(128 + signal.SIGTERM)
    finally:
        _working = False


def progress_map(work: Callable[[T], R], items: Iterable[T], *, workers: int, desc: str, unit: str = "grasp",
                 progress: bool = True, spawn: bool = False) -> list[R]:
    """``[work(item) for item in items]``, in order, with a progress bar on stderr.

    With ``workers`` above 1 the items go to that many processes, in chunks of about an eighth of
    each worker's share; ``work`` and the items must pickle. ``spawn`` starts them fresh instead of
    forking this one, with OpenCV on one thread in each. An interrupt (Ctrl-C, or SIGTERM under the
    commands) stops the workers at once, their work cleaning up after itself; a worker also stops when
    this process dies any other way (Linux).
    """
    items = list(items)
    bar = partial(progress_bar, total=len(items), desc=desc, unit=unit, enabled=progress)
    if workers <= 1:
        return list(bar(map(work, items)))
    size = max(1, len(items) // (8 * workers))
    # A forked child inherits OpenCV's thread pool mid-state: setting its threads there can hang.
    # Named, not the default: from Python 3.14 that is forkserver, whose workers are not this process's children.
    context = get_context("spawn" if spawn else "fork")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker,
                             initargs=(os.getpid(), spawn)) as pool:
        # Chunks as futures of their own, not Executor.map: on an interrupt map cancels the pending ones,
        # and the pool then fails on them as it finds its workers stopped (Python 3.11). The workers start
        # as the chunks are submitted, ignoring Ctrl-C: this process handles it, and stops them.
        with sigint_ignored():
            chunks = [pool.submit(_run_chunk, work, items[i : i + size]) for i in range(0, len(items), size)]
        try:
            return list(bar(result for chunk in chunks for result in chunk.result()))
        except BaseException:
            # Stop the running chunks too (Python 3.14 has terminate_workers()); leaving the block then
            # does not wait on them: the pool finds its workers gone and fails what is left.
            for process in list((pool._processes or {}).values()):
                process.terminate()
            raise
