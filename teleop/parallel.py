"""Work mapped over worker processes with a progress bar: simulation, dataset building, evaluation."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from multiprocessing import get_context
from typing import TypeVar

import cv2

from teleop.live import sigint_ignored
from teleop.progress import progress_bar

__all__ = ["progress_map"]

T = TypeVar("T")
R = TypeVar("R")


def _init_worker(one_thread: bool) -> None:
    """In each worker, first: SIGTERM ends it (a forked worker inherits the command's handler, which
    turns SIGTERM into Ctrl-C, and would not end on the pool's terminate()); OpenCV on one thread."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if one_thread:
        cv2.setNumThreads(1)  # one core per worker: OpenCV would otherwise spread over all of them


def _run_chunk(work: Callable[[T], R], chunk: list[T]) -> list[R]:
    return [work(item) for item in chunk]


def progress_map(work: Callable[[T], R], items: Iterable[T], *, workers: int, desc: str, unit: str = "grasp",
                 progress: bool = True, spawn: bool = False) -> list[R]:
    """``[work(item) for item in items]``, in order, with a progress bar on stderr.

    With ``workers`` above 1 the items go to that many processes, in chunks of about an eighth of
    each worker's share; ``work`` and the items must pickle. ``spawn`` starts them fresh instead of
    forking this one, with OpenCV on one thread in each. An interrupt (Ctrl-C, or SIGTERM under the commands) stops the workers at
    once.
    """
    items = list(items)
    bar = partial(progress_bar, total=len(items), desc=desc, unit=unit, enabled=progress)
    if workers <= 1:
        return list(bar(map(work, items)))
    size = max(1, len(items) // (8 * workers))
    # A forked child inherits OpenCV's thread pool mid-state: setting its threads there can hang.
    # Named, not the default: from Python 3.14 that is forkserver.
    context = get_context("spawn" if spawn else "fork")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker, initargs=(spawn,)) as pool:
        try:
            # Chunks as futures of their own, not Executor.map: on an interrupt map cancels the pending
            # ones, and the pool then fails on them as it finds its workers stopped (Python 3.11). The
            # workers start as the chunks are submitted, ignoring Ctrl-C: this process handles it, and
            # stops them, a SIGTERM that lands while chunks are still being submitted included.
            with sigint_ignored():
                chunks = [pool.submit(_run_chunk, work, items[i : i + size]) for i in range(0, len(items), size)]
            return list(bar(result for chunk in chunks for result in chunk.result()))
        except BaseException:
            # Stop the running chunks too (Python 3.14 has terminate_workers()); leaving the block then
            # does not wait on them: the pool finds its workers gone and fails what is left.
            for process in list((pool._processes or {}).values()):
                process.terminate()
            raise
