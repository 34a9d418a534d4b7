"""SIGTERM stops every command as Ctrl-C does (its clean-up run, "interrupted", exit 130), pool workers
included; a Ctrl-C after the command returned is ignored."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

# A command of its own, run through the commands' framework (teleop.clikit.run_cli) in a child process.
COMMAND = """
import os, sys, time
from pathlib import Path
from teleop.clikit import Command, run_cli
import teleop.parallel
from teleop.parallel import progress_map

OUT = Path(sys.argv[1])
if os.environ.get("SLEEPER_SLOW_SUBMIT"):  # a main thread descheduled after its first chunk: a SIGTERM lands mid-submission
    class SlowSubmit(teleop.parallel.ProcessPoolExecutor):
        def submit(self, *args, **kwargs):
            future = super().submit(*args, **kwargs)
            time.sleep(2)
            return future
    teleop.parallel.ProcessPoolExecutor = SlowSubmit

def slow(i):
    os.write(1, f"worker {os.getpid()}\\n".encode())  # one write: workers share the pipe
    time.sleep(30)

def add_arguments(parser):
    parser.add_argument("workers", type=int)

def run(args):
    try:
        if args.workers:
            progress_map(slow, range(8), workers=args.workers, desc="t", progress=False)
        else:
            os.write(1, f"worker {os.getpid()}\\n".encode())  # one write: workers share the pipe
            time.sleep(30)
    finally:
        (OUT / "cleaned").write_text("")
    return 0

if __name__ == "__main__":
    import __main__
    sys.modules["sleeper"] = __main__
    sys.exit(run_cli("sleeper", "", {"sleep": Command("sleeper", "sleep")}, sys.argv[2:]))
"""


def _alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting for a reaper that may not reap)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"
    except (FileNotFoundError, ProcessLookupError):
        return False


def _start(tmp_path: Path, workers: int, *, slow_submit: bool = False) -> tuple[subprocess.Popen, set[int]]:
    script = tmp_path / "sleeper.py"
    script.write_text(COMMAND)
    env = {**os.environ, "SLEEPER_SLOW_SUBMIT": "1" if slow_submit else ""}
    child = subprocess.Popen([sys.executable, str(script), str(tmp_path), "sleep", str(workers)], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pids: set[int] = set()
    while len(pids) < max(workers, 1):
        line = child.stdout.readline()
        if not line:
            child.kill()
            raise AssertionError(f"the command ended before its workers started: {child.stderr.read()}")
        if line.startswith("worker "):
            pids.add(int(line.split()[1]))
    return child, pids


def _wait_gone(pids: set[int], timeout_s: float = 5.0) -> set[int]:
    deadline = time.monotonic() + timeout_s
    while (left := {p for p in pids if _alive(p)}) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


@pytest.mark.parametrize(("workers", "slow_submit"), [(0, False), (2, False), (2, True)])
def test_sigterm_is_a_ctrl_c_for_every_command_and_its_workers(tmp_path, workers, slow_submit):
    child, pids = _start(tmp_path, workers, slow_submit=slow_submit)
    child.send_signal(signal.SIGTERM)  # to the command alone, as a service manager or `kill` does
    try:
        _, err = child.communicate(timeout=10)
    finally:
        child.kill()
    left = _wait_gone(pids - {child.pid})
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert child.returncode == 130, err
    assert "sleeper sleep: interrupted" in err and "Traceback" not in err
    assert (tmp_path / "cleaned").exists()
    assert not left, "pool workers outlived the command"


def test_ctrl_c_is_ignored_once_a_command_line_run_returned(tmp_path):
    script = textwrap.dedent("""
        import signal, sys
        from teleop.clikit import run_cli
        from teleop.cli import COMMANDS
        before = signal.getsignal(signal.SIGINT)
        assert run_cli("teleop", "", COMMANDS, ["settings"]) == 0  # in-process: the caller's Ctrl-C kept
        assert signal.getsignal(signal.SIGINT) is before
        sys.argv = ["teleop", "settings"]
        assert run_cli("teleop", "", COMMANDS) == 0  # the command line's: exiting now, Ctrl-C ignored
        print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "True"
