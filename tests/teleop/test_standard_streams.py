"""The console scripts' standard streams (teleop.cli_start, teleop.clikit): closed ones, an encoding
that cannot write what is printed, a full disk behind standard output."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

# A command of its own, started as the console scripts are (teleop.cli_start.start, from the command line).
COMMAND = textwrap.dedent('''
    import os, subprocess, sys

    def add_arguments(parser):
        parser.add_argument("what")
        parser.add_argument("path", nargs="?")

    def run(args):
        if args.what == "streams":
            # a log opened first, then written to by a child that inherits standard error (libzmq,
            # a live system's children write there too)
            with open(args.path, "w") as log:
                subprocess.run([sys.executable, "-c", "import sys; sys.stderr.write('the child says')"], check=True)
                log.write("the log's own line")
            print([stream.isatty() for stream in (sys.stdin, sys.stdout, sys.stderr)], file=sys.stderr)
        elif args.what == "unicode":
            print("\u03c3 = F/A \u00b1 4.4e-09")
        elif args.what == "undecodable-path":
            print(os.fsdecode(b"/data/caf\\xe9.grasp"))
            print("via __stdout__", file=sys.__stdout__)
            print("last")
        elif args.what.startswith("lines"):
            for i in range(int(args.what[5:])):
                print(f"line {i}")
        elif args.what == "other-file":
            with open(args.path, "w") as full:
                full.write("x")
        return 0
''')
MAIN = ("import sys; from teleop.cli_start import start; from teleop.clikit import Command; "
        "sys.exit(start('speaker', '', lambda: {'say': Command('speaker_command', 'say')}, None))")


def speaker(tmp_path, *argv, env=None, **options) -> subprocess.CompletedProcess:
    (tmp_path / "speaker_command.py").write_text(COMMAND)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path]), **(env or {})}
    return subprocess.run([sys.executable, "-c", MAIN, "say", *argv], env=env, timeout=60, **options)


@pytest.mark.parametrize("closed", [0, 1, 2])
def test_a_closed_standard_stream_is_the_null_device_and_takes_no_file_s_place(tmp_path, closed):
    log = tmp_path / "session.log"
    proc = speaker(tmp_path, "streams", str(log), capture_output=True, text=True,
                   preexec_fn=lambda: os.close(closed))
    assert proc.returncode == 0, proc.stderr
    assert log.read_text() == "the log's own line"  # nothing meant for standard error in it
    assert proc.stderr == ("" if closed == 2 else "the child says[False, False, False]\n")


@pytest.mark.parametrize("env", [{"LC_ALL": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0"},
                                 {"PYTHONIOENCODING": "latin-1"}])
def test_what_the_encoding_of_standard_output_cannot_write_is_escaped_not_a_crash(tmp_path, env):
    proc = speaker(tmp_path, "unicode", env=env, capture_output=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(b"\\u03c3 = F/A ")


@pytest.mark.parametrize("lines", [3, 100_000])  # written at the end, or while the command runs
def test_a_full_disk_behind_standard_output_is_one_line_and_status_2(tmp_path, lines):
    with open("/dev/full", "w") as full:
        proc = speaker(tmp_path, f"lines{lines}", stdout=full, stderr=subprocess.PIPE, text=True)
    assert (proc.returncode, proc.stderr) == (
        2, "speaker say: error: cannot write standard output: No space left on device\n")


def test_a_full_disk_behind_another_file_is_not_called_standard_output_s(tmp_path):
    proc = speaker(tmp_path, "other-file", "/dev/full", capture_output=True, text=True)
    assert proc.returncode == 1 and "standard output" not in proc.stderr
    assert "OSError: [Errno 28] No space left on device" in proc.stderr


def test_utf8_mode_writes_an_undecodable_path_back_as_its_bytes_in_order(tmp_path):
    proc = speaker(tmp_path, "undecodable-path", env={"PYTHONUTF8": "1"}, capture_output=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == b"/data/caf\xe9.grasp\nvia __stdout__\nlast\n"
