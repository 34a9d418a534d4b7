"""Progress bars on stderr: redrawn live on a terminal, sparingly into a log file or a pipe.

A file or pipe keeps every redraw, so there a bar is drawn when it starts, at most every
:data:`LOG_INTERVAL_S` while it runs, and when it ends.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm

__all__ = ["LOG_INTERVAL_S", "progress_bar"]

LOG_INTERVAL_S = 30.0
TERMINAL_INTERVAL_S = 0.1  # tqdm's own


def progress_bar(iterable: Iterable[Any] | None = None, *, enabled: bool = True, **options: Any) -> tqdm:
    """A tqdm bar on stderr over ``iterable`` (or updated by hand), drawn only when ``enabled``.

    ``options`` go to :class:`tqdm.tqdm` (``desc``, ``unit``, ``total``, ...).
    """
    interval_s = TERMINAL_INTERVAL_S if sys.stderr.isatty() else LOG_INTERVAL_S
    return tqdm(iterable, file=sys.stderr, disable=not enabled, mininterval=interval_s,
                maxinterval=max(interval_s, 10.0), **options)
