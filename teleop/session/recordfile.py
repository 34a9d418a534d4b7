"""The file a recorder writes: created only when no other writer holds it, locked while recording.

Two recorders on one file would each write at their own offsets and leave a log that neither
recorded, while both report success. So a recorder creates its log exclusively (or, to replace
one, opens it without truncating), then takes an advisory exclusive lock on it (``flock``) and
keeps it until it closes the file; only then, holding the lock, does it cut a replaced log to
nothing. A second recorder, ``teleop label`` (which holds the lock while it rewrites a log) and
``teleop recover --out`` (which would rename a file over it) are refused while the lock is held,
naming the process that holds it where the system says (``/proc/locks``, Linux).

A rewrite of a log (``teleop label``, ``teleop recover --out``: :func:`rewriting`) is written to
``<log>.partial`` and moved over the log; it holds that file's lock, exclusively, until then. The
log's own lock is no token for it: a rewrite takes it shared (NFS grants a read-only file no
other), and two rewrites at once would write one ``.partial``, the later one's log dropping the
earlier one's changes. So a second rewrite is refused too, as a recorder on the log is.

Locks are advisory: they guard against this package's own writers, not against other programs.
Where ``fcntl`` is missing (Windows) nothing is locked, as before.

Written bytes go to the operating system at once (:class:`LogSink`), so a SIGKILL loses none.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from teleop.errors import SessionLogError

try:
    import fcntl
except ImportError:  # Windows: no advisory locks
    fcntl = None

__all__ = ["LogSink", "create_log", "held_by", "holding", "refuse_if_held", "rewrite_path", "rewriting"]

log = logging.getLogger(__name__)

# How long a recorder tries to lock its log: long beside a check's instant, short beside a recording.
LOCK_GRACE_S = 0.5
_NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS}  # flock refused by the file system, not held
_unlockable: set[int] = set()  # file systems (st_dev) whose flock was refused so: said once, not tried again


class LogSink:
    """The file under the MCAP writer.

    Each write goes to the operating system at once (no user-space buffer that a SIGKILL
    would lose), and the offset where the last complete write ended is kept, so the bytes a
    failed write left behind can be cut off again. The MCAP writer writes whole records per
    call, so that offset is always a record boundary.
    """

    def __init__(self, file: IO[bytes]):
        self.file = file
        try:
            self.position = file.tell()
        except (OSError, AttributeError):
            self.position = 0

    def write(self, data: bytes) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < view.nbytes:  # a raw file may take part of a write
            n = self.file.write(view[done:])
            done = view.nbytes if n is None else done + n
        self.file.flush()
        self.position += view.nbytes
        return view.nbytes

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        self.file.flush()

    def cut_back(self) -> bool:
        """Truncate to the end of the last complete write; False if the file cannot be truncated."""
        try:
            self.file.truncate(self.position)
        except (OSError, AttributeError, ValueError) as exc:
            log.warning("could not cut the log back to byte %d: %s", self.position, exc)
            return False
        return True


def create_log(path: Path, *, overwrite: bool) -> IO[bytes]:
    """Open ``path`` for a new recording, locked until the returned (unbuffered) file is closed.

    Parameters
    ----------
    path : Path
        The session log to create.
    overwrite : bool
        Replace ``path`` if it exists; it is emptied only once this process holds its lock.

    Raises
    ------
    SessionLogError
        ``path`` exists and ``overwrite`` is False, another process holds it (a recorder
        still running, ``teleop label``), or it cannot be created.
    """
    flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
    try:
        # Never O_TRUNC: the bytes may be another recorder's, until the lock says otherwise.
        fd = os.open(path, flags | (0 if overwrite else os.O_EXCL), 0o666)
    except FileExistsError:
        refuse_if_held(path, "stop it first, or record into another file")
        raise SessionLogError(f"--out {path} exists: choose another name or pass --overwrite") from None
    except OSError as exc:
        raise SessionLogError(f"cannot create session log {path}: {exc.strerror or exc}") from exc
    try:
        if not _lock_within(fd, LOCK_GRACE_S):
            raise SessionLogError(_held_text(path, "stop it first, or record into another file"))
        if not _same_file(fd, path):  # replaced (`teleop label`) or removed between open and lock
            raise SessionLogError(f"session log {path} was replaced while it was being opened (`teleop label` "
                                  "rewrote it?): run again")
        os.ftruncate(fd, 0)
        return os.fdopen(fd, "wb", buffering=0)
    except OSError as exc:
        os.close(fd)
        raise SessionLogError(f"cannot create session log {path}: {exc.strerror or exc}") from exc
    except BaseException:
        os.close(fd)
        raise


def held_by(path: str | Path) -> int | None:
    """Whether another open file holds the lock of ``path`` or of its rewrite (:func:`rewrite_path`): its
    holder's PID, 0 where unknown; None if neither is held."""
    if fcntl is None:
        return None
    for locked in (path, rewrite_path(path)):
        try:
            fd = os.open(locked, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        except OSError:  # absent or unreadable: nothing to take it from
            continue
        try:
            if not _lock_within(fd, LOCK_GRACE_S, shared=True):  # another check may hold it for an instant
                return _holder_pid(os.fstat(fd)) or 0
        finally:
            os.close(fd)  # also drops the lock just taken
    return None


def refuse_if_held(path: str | Path, what_to_do: str) -> None:
    """Raise :class:`SessionLogError` if another process holds ``path``'s lock, saying ``what_to_do``."""
    if held_by(path) is not None:
        raise SessionLogError(_held_text(path, what_to_do))


@contextlib.contextmanager
def holding(path: str | Path, what_to_do: str) -> Iterator[None]:
    """Hold ``path``'s lock for the block (a rewrite of the log), refused as :func:`refuse_if_held` when held."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:  # the rewrite itself says what is wrong with the file
        yield
        return
    try:
        if not _lock_within(fd, LOCK_GRACE_S, shared=True):
            raise SessionLogError(_held_text(path, what_to_do))
        yield
    finally:
        os.close(fd)


def rewrite_path(path: str | Path) -> Path:
    """Where a rewrite of the log ``path`` is written before it is moved over it: ``<path>.partial``."""
    path = Path(path)
    return path.with_name(path.name + ".partial")


@contextlib.contextmanager
def rewriting(path: str | Path, what_to_do: str) -> Iterator[Path]:
    """Rewrite the log ``path`` in the block: yields :func:`rewrite_path`, exclusively locked, for the new
    log to be written into and moved over ``path``; ``path``'s lock is held meanwhile (:func:`holding`).

    A ``.partial`` a killed rewrite left is taken over. What of it is still there after the block (a
    rewrite that failed, or a rename done by other means) is removed.

    Raises
    ------
    SessionLogError
        Another process rewrites ``path`` (``teleop label``, ``teleop recover --out``) or records
        it (as :func:`refuse_if_held`, saying ``what_to_do``), or the ``.partial`` cannot be created.
    """
    tmp = rewrite_path(path)
    deadline = time.monotonic() + LOCK_GRACE_S
    while True:
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError as exc:
            raise SessionLogError(f"cannot write {tmp}, the rewrite of session log {path}: "
                                  f"{exc.strerror or exc}") from exc
        if not _lock_within(fd, max(deadline - time.monotonic(), 0.0)):
            os.close(fd)
            raise SessionLogError(_held_text(path, what_to_do))
        if _same_file(fd, tmp):
            break
        # The rewrite before this one moved it over the log (or removed it) as it ended: a fresh one.
        os.close(fd)
        if time.monotonic() > deadline:
            raise SessionLogError(_held_text(path, what_to_do))
    try:
        with holding(path, what_to_do):
            yield tmp
    finally:
        with contextlib.suppress(OSError):  # must not hide the error that ended the block
            if _same_file(fd, tmp):  # still the one locked: nobody else's
                tmp.unlink()
        os.close(fd)


def _lock_within(fd: int, grace_s: float, *, shared: bool = False) -> bool:
    """Lock, trying again for ``grace_s``: another process's check (:func:`held_by`) holds it for an instant.
    ``shared``: a check or a rewrite on a read-only descriptor (NFS grants those only a shared lock),
    which a recorder's exclusive one still excludes."""
    deadline = time.monotonic() + grace_s
    while not _try_lock(fd, shared):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _try_lock(fd: int, shared: bool = False) -> bool:
    """Whether ``fd``'s lock was free (and is now this process's); True where locks are not to be had."""
    if fcntl is None or (device := os.fstat(fd).st_dev) in _unlockable:
        return True
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LOCKS:
            raise
        # A file system without flock (some network mounts): record as before, unguarded.
        _unlockable.add(device)
        log.warning("session logs cannot be locked on this file system (%s): two writers of one log are not "
                    "refused", exc)
    return True


def _same_file(fd: int, path: Path) -> bool:
    try:
        now = os.stat(path)
    except FileNotFoundError:
        return False
    opened = os.fstat(fd)
    return (opened.st_dev, opened.st_ino) == (now.st_dev, now.st_ino)


def _held_text(path: str | Path, what_to_do: str) -> str:
    pid = held_by(path)
    by = f" (PID {pid})" if pid else ""
    return (f"session log {path} is held by another process{by}, a recorder still writing it or "
            f"`teleop label` or `teleop recover --out` rewriting it: {what_to_do}")


def _holder_pid(stat: os.stat_result) -> int | None:
    """The PID ``/proc/locks`` gives for the flock on the file of ``stat`` (Linux), else None."""
    wanted = f"{os.major(stat.st_dev):02x}:{os.minor(stat.st_dev):02x}:{stat.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()  # "1: FLOCK ADVISORY WRITE <pid> <dev>:<inode> 0 EOF"; "->" marks a waiter
        if len(fields) > 5 and fields[1] == "FLOCK" and fields[5] == wanted:
            return int(fields[4])
    return None
