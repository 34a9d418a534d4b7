"""The small framework behind the ``teleop``, ``estimator`` and ``haptics`` commands.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported only when their subcommand runs, so
``--help`` is fast and a run never imports what it does not use (torch above all).
Errors the packages raise on purpose (every one a :class:`~teleop.errors.ComplianceTeleopError`)
are printed as one line, never a traceback; so is a command's optional extra that is not installed
(``Command.extra``). From the command line, standard output writes what its encoding cannot as
backslash escapes (as standard error does), and a failing write to it (a full disk) is one line too.
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import importlib
import io
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from teleop.errors import ComplianceTeleopError, TeleopError

PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def output_file(option: str, value: str | None, *, suffixes: Sequence[str] = ()) -> Path | None:
    """The file an output option names, checked before the work that fills it: not a folder, one of
    ``suffixes`` (when given), and its folder made, so that a long run does not end in an error
    after its work. None stays None.

    Raises
    ------
    TeleopError
        The path is a folder or ends in a path separator, has another suffix, or its folder cannot be
        made (named with ``option``).
    """
    if value is None:
        return None
    path = Path(value)
    if path.is_dir():
        raise TeleopError(f"{option} {value}: is a folder; expected a file name")
    if value.endswith(tuple(sep for sep in (os.sep, os.altsep) if sep)):
        # Path() drops the separator: the file would take the folder's name.
        raise TeleopError(f"{option} {value}: names a folder (it ends in {value[-1]}); expected a file name")
    if suffixes and path.suffix.lower() not in suffixes:
        raise TeleopError(f"{option} {value}: expected a name ending in {', '.join(suffixes)}")
    blocker = file_in_the_way(path.parent)
    if blocker is not None:
        raise TeleopError(f"{option} {value}: {blocker} is not a directory; expected a folder there (or nothing)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise TeleopError(f"{option} {value}: cannot make its folder {path.parent} ({exc.strerror or exc})") from exc
    return path


def file_in_the_way(folder: Path) -> Path | None:
    """The first of ``folder`` and its parents that exists, when it is not a folder: what makes
    ``folder.mkdir(parents=True)`` fail with an error ("File exists", "Not a directory") that does not
    name it. None when nothing is in the way."""
    existing = next((p for p in (folder, *folder.parents) if p.exists()), None)
    return existing if existing is not None and not existing.is_dir() else None


def help_literal(value: object) -> str:
    """``value`` as text to put verbatim in an argparse help string: every ``%`` doubled, since argparse
    %-formats help strings (``%(default)s``) and a path with a ``%`` in it (the install folder's)
    would break or garble ``--help``."""
    return str(value).replace("%", "%%")


def _finite(text: str) -> float:
    """``text`` as a float; nan when it is none."""
    try:
        return float(text)
    except ValueError:
        return math.nan


def positive_number(text: str) -> float:
    """An argparse type: a finite number > 0 (a time, a rate), refused by argparse with what was expected."""
    value = _finite(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number > 0, finite")
    return value


def non_negative_number(text: str) -> float:
    """An argparse type: a finite number >= 0 (a wait that may be none), refused by argparse with what was
    expected (``time.sleep`` refuses a negative, nan or infinite one only once the work is under way)."""
    value = _finite(text)
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number >= 0, finite")
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number >= 0 (a seed, a count that may be none), refused by argparse with
    what was expected (numpy refuses a negative seed only after the work began, with a traceback)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 0")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number >= 1 (a count of runs or grasps: none of them has no median)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 1")
    return value


#: The distribution the commands come from: its version, its extras.
DISTRIBUTION = "compliance-teleop"

#: The top-level modules each optional extra of pyproject.toml installs, for the extras commands name.
EXTRA_MODULES = {"train": frozenset({"torch", "onnx", "onnxscript"})}


@dataclass(frozen=True)
class Command:
    module: str
    help: str
    extra: str | None = None  # the optional extra its run needs (its --help does not): a key of EXTRA_MODULES


def _missing_extra(command: Command, exc: ImportError) -> bool:
    """Whether ``exc`` is a module of ``command``'s extra not being installed."""
    return command.extra is not None and (exc.name or "").partition(".")[0] in EXTRA_MODULES[command.extra]


class _DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends ``(default: ...)`` unless the option is required, a flag, has no default (None or
    empty) or says its own."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.required or action.default in (None, "") or action.nargs == 0 or "(default" in text:
            return text
        return super()._get_help_string(action)


def hangup_ignored() -> bool:
    """SIGHUP is ignored now (``nohup``, a parent's choice): a process keeps it so, not stopping on it."""
    return signal.getsignal(signal.SIGHUP) is signal.SIG_IGN


class Terminated(KeyboardInterrupt):
    """A stop signal other than Ctrl-C (SIGTERM, SIGHUP), raised as a KeyboardInterrupt so that whatever
    cleans up after a Ctrl-C cleans up after it too; it keeps its signal for the exit status (a
    supervisor reads 130 as a Ctrl-C at the terminal, 143 as its own SIGTERM)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


#: What a command that a signal stopped says it was.
_STOPPED_BY = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated", signal.SIGHUP: "hung up"}


def say_stopped(what: str, exc: KeyboardInterrupt) -> int:
    """Say on stderr that ``what`` was stopped by ``exc``'s signal, as ``<what>: interrupted`` (Ctrl-C),
    ``terminated`` (SIGTERM) or ``hung up`` (SIGHUP).

    Parameters
    ----------
    what
        The command stopped: ``prog`` or ``prog command``.
    exc
        The interrupt: a plain KeyboardInterrupt is a Ctrl-C, a :class:`Terminated` names its signal.

    Returns
    -------
    int
        The exit status a shell gives a process that signal ends: 128 + its number.
    """
    signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
    print(f"{what}: {_STOPPED_BY[signum]}", file=sys.stderr)
    return 128 + signum


@contextlib.contextmanager
def sigterm_as_ctrl_c() -> Iterator[None]:
    """SIGTERM and SIGHUP (a closed terminal; unless ignored, as under ``nohup``) raise :class:`Terminated`
    (a KeyboardInterrupt) meanwhile, as Ctrl-C does, so a command cleans up after it (its pool workers or
    child processes stopped, temporary files removed) and says it was terminated, instead of dying
    alone. Only the first: a second one must not cut that clean-up short. :func:`run_cli` runs every
    command so (in the main thread); the services that stop on them (:class:`~teleop.live.StopSignals`)
    replace it while they serve."""
    def interrupt(signum: int, frame: FrameType | None) -> None:
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) is interrupt:
                signal.signal(sig, signal.SIG_IGN)
        raise Terminated(signum)

    with on_stop_signals(interrupt):
        yield


@contextlib.contextmanager
def on_stop_signals(handler: Callable[[int, FrameType | None], Any]) -> Iterator[None]:
    """``handler`` for SIGTERM, and for SIGHUP unless it is ignored (``nohup``), meanwhile; the
    previous handlers restored after."""
    wanted = [signal.SIGTERM] + ([] if hangup_ignored() else [signal.SIGHUP])
    previous = {signum: signal.signal(signum, handler) for signum in wanted}
    try:
        yield
    finally:
        for signum, before in previous.items():
            signal.signal(signum, before)


def _ignore_late_ctrl_c() -> None:
    """Once the command returned, a Ctrl-C no longer interrupts anything: ignored, lest it kill the
    process during the interpreter's shutdown (joining threads, closing pools) with no word, after
    complete work. Only for a run from the real command line (``argv`` not given), in the main
    thread: a caller that runs commands in-process keeps its Ctrl-C."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class StandardOutputError(OSError):
    """A write to standard output failed (a full disk, an I/O error); its errno and strerror are the
    system's. A reader that left stays a BrokenPipeError."""


class _StandardOutputFile(io.FileIO):
    """Standard output's file descriptor, whose failing writes raise :class:`StandardOutputError`:
    told apart so from a failing write to any other file, which stays the error it is."""

    def write(self, data: Any) -> int | None:
        try:
            return super().write(data)
        except (BlockingIOError, BrokenPipeError):
            raise
        except OSError as exc:
            raise StandardOutputError(exc.errno, exc.strerror) from exc


def _write_unwritable(error: UnicodeError) -> tuple[str | bytes, int]:
    """A codec error handler: a path's undecodable bytes (``os.fsdecode``'s surrogates) as they were,
    anything else the encoding cannot write as backslash escapes."""
    try:
        return codecs.lookup_error("surrogateescape")(error)
    except UnicodeError:
        return codecs.lookup_error("backslashreplace")(error)


_UNWRITABLE = "teleop-unwritable"
codecs.register_error(_UNWRITABLE, _write_unwritable)


def _check_standard_output() -> None:
    """Replace the interpreter's ``sys.stdout`` (and ``sys.__stdout__``, lest the two interleave out of
    order) by one on the same descriptor, with the same encoding and buffering, that writes what its
    encoding cannot as backslash escapes (a path's undecodable bytes as they were) and raises
    :class:`StandardOutputError` when a write fails. Nothing when ``sys.stdout`` is not the
    interpreter's own (a caller's capture) or has no descriptor."""
    out = sys.stdout
    if out is not sys.__stdout__ or not isinstance(out, io.TextIOWrapper):
        return
    try:
        fd = out.fileno()
        out.flush()
    except (OSError, ValueError):  # no descriptor, or already failing: left as it is
        return
    raw = _StandardOutputFile(fd, "w", closefd=False)
    binary = raw if isinstance(out.buffer, io.FileIO) else io.BufferedWriter(raw)  # python -u: unbuffered
    sys.stdout = sys.__stdout__ = io.TextIOWrapper(binary, encoding=out.encoding, errors=_UNWRITABLE,
                                                   line_buffering=out.line_buffering, write_through=out.write_through)


def _discard_standard_output() -> None:
    """Standard output on the null device from now on: what it still buffers would fail again when
    Python flushes it at exit, with a traceback."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


class _VersionAction(argparse.Action):
    """``--version``: print ``<prog> <version>`` and exit 0. The version is looked up only when asked,
    so that no other run imports what finds it."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        import importlib.metadata

        try:
            version = importlib.metadata.version(DISTRIBUTION)
        except importlib.metadata.PackageNotFoundError:  # run from a source tree on sys.path
            version = f"(version unknown: the {DISTRIBUTION} distribution is not installed)"
        print(f"{parser.prog} {version}")
        parser.exit()


def _parsed(prog: str, description: str, commands: Mapping[str, Command], argv: list[str],
            chosen: str | None) -> argparse.Namespace:
    """``argv`` parsed, with the ``chosen`` subcommand's module imported for its options; logging set up."""
    parser = argparse.ArgumentParser(  # the module docstring, without its reStructuredText literals
        prog=prog, description=description.replace("``", ""), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (repeatable)")
    parser.add_argument("--version", action=_VersionAction, help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    sub.required = True
    for name, command in commands.items():
        p = sub.add_parser(
            name, help=command.help, description=command.help,
            formatter_class=_DefaultsHelpFormatter,
        )
        if name == chosen:
            module = importlib.import_module(command.module)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    args = parser.parse_args(argv)
    args._command_line = [prog, *argv]  # as typed, for outputs that say how they were made
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    return args


def run_cli(
    prog: str,
    description: str,
    commands: Mapping[str, Command],
    argv: Sequence[str] | None = None,
) -> int:
    """Parse ``argv``, import the chosen subcommand's module and run it. From the command line
    (``argv`` None) standard output is checked (:class:`StandardOutputError`) meanwhile."""
    argv_given = argv
    if argv_given is None:
        _check_standard_output()
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    try:
        args = _parsed(prog, description, commands, argv, chosen)
    except KeyboardInterrupt as exc:  # while the command's module imports (numpy, scipy, cv2: seconds)
        return say_stopped(f"{prog}{'' if chosen is None else ' ' + chosen}", exc)
    try:
        with sigterm_as_ctrl_c() if threading.current_thread() is threading.main_thread() else contextlib.nullcontext():
            try:
                status = int(args._run(args) or 0)
                sys.stdout.flush()  # here, where a failure is told as the command's, not at the exit
                return status
            finally:
                if argv_given is None:
                    _ignore_late_ctrl_c()
    except ComplianceTeleopError as exc:
        print(f"{prog} {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except ImportError as exc:
        command = commands[args.command]
        if not _missing_extra(command, exc):
            raise
        print(f"{prog} {args.command}: error: needs the '{command.extra}' extra ({exc}): "
              f"pip install '{DISTRIBUTION}[{command.extra}]' (in a checkout: "
              f"pip install -c constraints.txt -e '.[{command.extra}]')", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (sigterm_as_ctrl_c)
        return say_stopped(f"{prog} {args.command}", exc)
    except BrokenPipeError:
        # The reader left (`| head`): not this command's error.
        _discard_standard_output()
        return 1
    except StandardOutputError as exc:  # a write to stdout, not to another file (_StandardOutputFile)
        _discard_standard_output()
        print(f"{prog} {args.command}: error: cannot write standard output: {exc.strerror or exc}", file=sys.stderr)
        return 2
