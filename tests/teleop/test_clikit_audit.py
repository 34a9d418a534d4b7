"""teleop.clikit: the argparse number types, output file checks, exit statuses and the first stop signal."""

from __future__ import annotations

import argparse
import io
import logging
import os
import signal
import sys
import threading
import time
import types

import pytest

from teleop.clikit import (
    PLOT_SUFFIXES,
    Command,
    Terminated,
    file_in_the_way,
    non_negative_int,
    non_negative_number,
    output_file,
    positive_int,
    positive_number,
    run_cli,
    say_stopped,
    sigterm_as_ctrl_c,
)
from teleop.clikit import _DefaultsHelpFormatter as DefaultsHelpFormatter
from teleop.errors import TeleopError


@pytest.mark.parametrize("kind", [positive_number, non_negative_number, non_negative_int, positive_int])
def test_text_that_is_no_number_is_refused_not_taken_as_zero(kind):
    with pytest.raises(argparse.ArgumentTypeError, match="'abc': expected"):
        kind("abc")


@pytest.mark.parametrize("kind, text", [(positive_int, "0"), (positive_int, "-3"), (non_negative_int, "-1"),
                                        (non_negative_int, "1.5")])
def test_a_whole_number_out_of_range_is_refused(kind, text):
    with pytest.raises(argparse.ArgumentTypeError, match=rf"'{text}': expected a whole number >= [01]"):
        kind(text)


@pytest.mark.parametrize("kind, text, value", [(positive_int, "1", 1), (non_negative_int, "0", 0),
                                               (non_negative_int, "7", 7)])
def test_a_whole_number_in_range_is_taken(kind, text, value):
    assert kind(text) == value


def test_no_output_file_stays_none():
    assert output_file("--out", None) is None


def test_an_output_file_that_is_a_folder_is_refused_naming_the_option(tmp_path):
    with pytest.raises(TeleopError, match=r"^--out .*: is a folder; expected a file name"):
        output_file("--out", str(tmp_path))


def test_an_output_file_ending_in_a_separator_is_refused(tmp_path):
    with pytest.raises(TeleopError, match=r"^--out .*: names a folder \(it ends in /\)"):
        output_file("--out", f"{tmp_path}/new/")
    assert not (tmp_path / "new").exists()


def test_an_output_file_suffix_is_checked_whatever_its_case(tmp_path):
    assert output_file("--plot", str(tmp_path / "fig.PNG"), suffixes=PLOT_SUFFIXES) == tmp_path / "fig.PNG"
    with pytest.raises(TeleopError, match=r"^--plot .*: expected a name ending in \.png, \.pdf, \.svg"):
        output_file("--plot", str(tmp_path / "fig.txt"), suffixes=PLOT_SUFFIXES)


def test_an_output_files_missing_folders_are_made_before_the_work(tmp_path):
    path = output_file("--out", str(tmp_path / "a" / "b" / "x.json"))
    assert path == tmp_path / "a" / "b" / "x.json" and path.parent.is_dir() and not path.exists()


def test_an_output_file_under_a_plain_file_names_that_file(tmp_path):
    (tmp_path / "plain").write_text("x")
    with pytest.raises(TeleopError, match=r"plain is not a directory"):
        output_file("--out", str(tmp_path / "plain" / "sub" / "x.json"))
    assert file_in_the_way(tmp_path / "plain" / "sub") == tmp_path / "plain"


def test_an_existing_folder_is_nothing_in_the_way(tmp_path):
    assert file_in_the_way(tmp_path) is None and file_in_the_way(tmp_path / "not" / "yet") is None


@pytest.mark.parametrize("exc, said, status", [
    (KeyboardInterrupt(), "interrupted", 130),
    (Terminated(signal.SIGTERM), "terminated", 143),
    (Terminated(signal.SIGHUP), "hung up", 129),
])
def test_a_stopped_command_says_by_what_and_exits_as_a_shell_would(capsys, exc, said, status):
    assert say_stopped("teleop demo", exc) == status
    assert capsys.readouterr().err == f"teleop demo: {said}\n"


def test_only_the_first_sigterm_interrupts_a_command_later_ones_are_ignored_until_it_ends():
    before = signal.getsignal(signal.SIGTERM)
    with sigterm_as_ctrl_c():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)  # a hang guard: the handler interrupts it
            raise AssertionError("SIGTERM did not interrupt")
        except Terminated as exc:
            assert exc.signum == signal.SIGTERM
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGTERM)  # the clean-up is not cut short by a second one
            time.sleep(0.01)
    assert signal.getsignal(signal.SIGTERM) is before


def _running(monkeypatch, run) -> dict[str, Command]:
    """A one-command table whose command runs ``run(args)``."""
    module = types.SimpleNamespace(add_arguments=lambda parser: None, run=run)
    monkeypatch.setitem(sys.modules, "audit_cli", module)
    return {"go": Command("audit_cli", "a command", extra="train")}


def test_a_missing_submodule_of_the_extra_says_what_to_install(monkeypatch, capsys):
    def run(args):
        raise ImportError("No module named 'torch.nn'", name="torch.nn")

    assert run_cli("prog", "doc", _running(monkeypatch, run), ["go"]) == 2
    assert "needs the 'train' extra" in capsys.readouterr().err


def test_a_command_run_in_process_leaves_ctrl_c_as_it_was(monkeypatch):
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert run_cli("prog", "doc", _running(monkeypatch, lambda args: 0), ["go"]) == 0
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_commands_output_is_flushed_before_run_cli_returns(monkeypatch):
    """So that a failing write (a full disk) is told as the command's error, not lost at the exit."""
    out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
    monkeypatch.setattr(sys, "stdout", out)
    assert run_cli("prog", "doc", _running(monkeypatch, lambda args: print("said")), ["go"]) == 0
    assert out.buffer.getvalue() == b"said\n"


def test_twice_verbose_logs_debug_messages(monkeypatch):
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    root.handlers[:] = []  # basicConfig configures only a root logger with no handler
    try:
        assert run_cli("prog", "doc", _running(monkeypatch, lambda args: 0), ["-vv", "go"]) == 0
        assert root.level == logging.DEBUG
        assert run_cli("prog", "doc", _running(monkeypatch, lambda args: 0), ["-vvv", "go"]) == 0
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)


def test_a_required_options_help_does_not_claim_a_default():
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter)
    parser.add_argument("--name", required=True, default="given", help="the name")
    parser.add_argument("--rate", default=2.0, help="the rate")
    text = parser.format_help()
    assert "the name (default" not in text and "the rate (default: 2.0)" in text


def test_a_ctrl_c_while_the_command_module_imports_is_said_with_its_name_and_status_130(monkeypatch, capsys):
    def add_arguments(parser):
        raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "audit_slow_cli", types.SimpleNamespace(add_arguments=add_arguments, run=None))
    assert run_cli("prog", "doc", {"go": Command("audit_slow_cli", "slow to import")}, ["go"]) == 130
    assert capsys.readouterr().err == "prog go: interrupted\n"


def _from_the_command_line(monkeypatch, commands: dict[str, Command]) -> int:
    """``run_cli`` as the console scripts call it (``argv`` None), Ctrl-C put back after."""
    monkeypatch.setattr(sys, "argv", ["prog", "go"])
    before = signal.getsignal(signal.SIGINT) if threading.current_thread() is threading.main_thread() else None
    try:
        return run_cli("prog", "doc", commands)
    finally:
        if before is not None:
            signal.signal(signal.SIGINT, before)


def test_a_callers_own_standard_output_is_left_in_place(monkeypatch, tmp_path):
    with (tmp_path / "out.txt").open("w") as own:
        monkeypatch.setattr(sys, "stdout", own)
        monkeypatch.setattr(sys, "__stdout__", sys.__stdout__)
        assert _from_the_command_line(monkeypatch, _running(monkeypatch, lambda args: print("said"))) == 0
        assert sys.stdout is own
    assert (tmp_path / "out.txt").read_text() == "said\n"


def test_a_command_run_from_the_command_line_outside_the_main_thread_leaves_signals_alone(monkeypatch):
    commands = _running(monkeypatch, lambda args: 0)
    results: list[object] = []

    def target():
        try:
            results.append(_from_the_command_line(monkeypatch, commands))
        except Exception as exc:  # noqa: BLE001 - reported by the assert below
            results.append(exc)

    thread = threading.Thread(target=target)
    thread.start()
    thread.join(timeout=30)
    assert results == [0]
