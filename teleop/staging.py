"""Write an output beside its destination and rename it into place only once it is complete.

A command interrupted (Ctrl-C, SIGTERM, an error) while it writes a file in place leaves a
truncated file where the earlier, good one was, and a reader takes it up. :func:`staged` and
:func:`staged_dir` hand out a temporary path in the destination's own folder (so the rename is
one atomic ``os.replace`` on the same file system), named ``.<name>.<random>.partial`` (hidden,
and with no suffix a reader looks for, such as ``.onnx``), rename it over the destination when
the block ends normally, and remove it on any exception, KeyboardInterrupt included: the earlier
output stays as it was.

A writer that picks its format from the file name (``matplotlib``'s ``savefig``) must be told the
format, since the temporary's name ends in ``.partial``.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["partial_path", "staged", "staged_dir"]


def partial_path(path: str | Path) -> Path:
    """A fresh temporary name beside ``path``: ``.<name>.<random>.partial`` in the same folder."""
    path = Path(path)
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}.partial")


@contextmanager
def staged(*paths: str | Path) -> Iterator[Path | tuple[Path, ...]]:
    """Temporaries for ``paths``, renamed over them together when the block ends without an exception.

    Parameters
    ----------
    *paths : str or Path
        The destination files (their folders must exist). With one path the block gets one
        temporary, with several a tuple of them in the same order.

    Yields
    ------
    Path or tuple of Path
        ``.<name>.<random>.partial`` beside each destination; the block writes them.

    Notes
    -----
    On success each temporary the block wrote replaces its destination, in the order given, back
    to back after all are complete (a destination whose temporary the block did not write is left
    as it is). Put last the file a reader looks at first. On any exception, KeyboardInterrupt
    included, every temporary is removed and no destination is touched (unless the exception
    came during the renames themselves, after the first ones). A temporary that cannot be removed
    (a read-only file system) stays: the block's own error is the one raised.
    """
    destinations = [Path(p) for p in paths]
    temporaries = [partial_path(p) for p in destinations]
    try:
        yield temporaries[0] if len(temporaries) == 1 else tuple(temporaries)
        for temporary, destination in zip(temporaries, destinations, strict=True):
            if temporary.exists():
                os.replace(temporary, destination)
    finally:
        for temporary in temporaries:
            # A read-only file system refuses even a missing file's unlink (EROFS): that must not
            # replace the error that brought us here.
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)


def _carry(old: Path, new: Path, drop: Callable[[str], bool] | None = None) -> None:
    """Link (or copy) into ``new`` every entry of ``old`` that ``new`` does not hold and ``drop``
    (given the entry's name) does not reject; ``old`` keeps them."""
    for entry in old.iterdir():
        target = new / entry.name
        if target.exists() or target.is_symlink() or (drop is not None and drop(entry.name)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.copytree(entry, target, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(entry, target)


def _link_or_copy(source: str | Path, target: str | Path) -> None:
    if os.path.islink(source):
        os.symlink(os.readlink(source), target)
        return
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


@contextmanager
def staged_dir(path: str | Path, *, drop: Callable[[str], bool] | None = None) -> Iterator[Path]:
    """A temporary folder beside ``path``, swapped in for it when the block ends without an exception.

    Parameters
    ----------
    path : str or Path
        The destination folder; it may exist (its parent must).
    drop : callable, optional
        Given the name of an entry of the existing ``path`` that the block did not rewrite, true
        when that entry must not be carried over (an earlier run's output this run did not
        write again, such as another log's figures); default: every entry is carried.

    Yields
    ------
    Path
        An empty folder ``.<name>.<random>.partial`` beside ``path``; the block fills it.

    Notes
    -----
    On success, when ``path`` exists, the entries of it the block did not write (and ``drop``
    does not reject) are carried into the new folder (hard links, or copies where links fail: the old folder keeps them), then
    ``path`` is renamed aside, the new folder renamed to ``path`` and the old one removed. Between
    those two renames (microseconds) ``path`` does not exist; a reader never sees old and new
    files mixed. When ``path`` holds the working folder, the new entries are instead renamed into
    it one by one, oldest first (a reader may then see a mix for as long). On any exception, KeyboardInterrupt included, the temporary folder is removed and
    ``path`` is untouched.
    """
    path = Path(os.path.abspath(path))
    temporary = partial_path(path)
    temporary.mkdir()
    try:
        yield temporary
        if path.is_dir() and (Path.cwd() == path or path in Path.cwd().parents):
            # Renaming the working folder would leave this process in a removed one: move the
            # entries over instead, in the order they were written (a page written last goes last).
            written = {entry.name for entry in temporary.iterdir()}
            for entry in sorted(temporary.iterdir(), key=lambda p: p.stat().st_mtime_ns):
                os.replace(entry, path / entry.name)
            for entry in list(path.iterdir()) if drop is not None else ():
                if entry.name not in written and drop(entry.name):
                    if entry.is_dir() and not entry.is_symlink():
                        shutil.rmtree(entry, ignore_errors=True)
                    else:
                        entry.unlink(missing_ok=True)
        elif path.is_dir():
            _carry(path, temporary, drop)
            aside = partial_path(path)
            os.rename(path, aside)
            try:
                os.rename(temporary, path)
            except BaseException:
                os.rename(aside, path)  # the old folder back where it was
                raise
            shutil.rmtree(aside, ignore_errors=True)
        else:
            os.replace(temporary, path)
    finally:
        if temporary.exists():
            shutil.rmtree(temporary, ignore_errors=True)
