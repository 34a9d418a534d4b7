"""SIGTERM stops every command as Ctrl-C does (its clean-up run, pool workers included), but says it
was terminated, with exit status 143 (128 + SIGTERM; a Ctrl-C's is 130); a Ctrl-C after the command
returned is ignored, and one while the command line starts is one line too."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
import types
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


@pytest.mark.slow
@pytest.mark.parametrize(("workers", "slow_submit"), [(0, False), (2, False), (2, True)])
def test_sigterm_cleans_up_as_a_ctrl_c_for_every_command_and_its_workers_and_says_terminated(tmp_path, workers, slow_submit):
    child, pids = _start(tmp_path, workers, slow_submit=slow_submit)
    child.send_signal(signal.SIGTERM)  # to the command alone, as a service manager or `kill` does
    try:
        _, err = child.communicate(timeout=10)
    finally:
        child.kill()
    left = _wait_gone(pids - {child.pid})
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert child.returncode == 143, err
    assert err.rstrip().endswith("sleeper sleep: terminated") and "Traceback" not in err
    assert (tmp_path / "cleaned").exists()
    assert not left, "pool workers outlived the command"


def test_ctrl_c_is_ignored_once_a_command_line_run_returned(tmp_path):
    script = textwrap.dedent("""
        import signal, sys
        from teleop.clikit import run_cli
        from teleop.cli import commands
        before = signal.getsignal(signal.SIGINT)
        assert run_cli("teleop", "", commands(), ["settings"]) == 0  # in-process: the caller's Ctrl-C kept
        assert signal.getsignal(signal.SIGINT) is before
        sys.argv = ["teleop", "settings"]
        assert run_cli("teleop", "", commands()) == 0  # the command line's: exiting now, Ctrl-C ignored
        print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "True"


@pytest.mark.parametrize(("signum", "status", "said"), [(signal.SIGINT, 130, "interrupted"),
                                                      (signal.SIGTERM, 143, "terminated"),
                                                      (signal.SIGHUP, 129, "hung up")])
def test_the_exit_status_names_the_stop_signal(monkeypatch, capsys, signum, status, said):
    from teleop.clikit import Command, hangup_ignored, run_cli

    if signum == signal.SIGHUP and hangup_ignored():
        pytest.skip("SIGHUP is ignored here (nohup): the commands keep it so")
    command = types.ModuleType("stopped_command")
    command.add_arguments = lambda parser: None
    command.run = lambda args: signal.raise_signal(signum) or time.sleep(5)
    monkeypatch.setitem(sys.modules, "stopped_command", command)
    before = signal.getsignal(signal.SIGTERM)
    assert run_cli("sleeper", "", {"stop": Command("stopped_command", "stop")}, ["stop"]) == status
    assert capsys.readouterr().err == f"sleeper stop: {said}\n"
    assert signal.getsignal(signal.SIGTERM) == before  # the command's handler put back


# The console script's own lines (pyproject.toml's [project.scripts]): its package's cli module is imported
# before main() runs. The Ctrl-C is raised while teleop.clikit imports, as a finder for it would.
STARTUP = """
import sys

class CtrlC:
    def find_spec(self, name, path=None, target=None):
        if name == "teleop.clikit":
            raise KeyboardInterrupt

sys.meta_path.insert(0, CtrlC())
from {package}.cli import main
sys.exit(main(["--help"]))
"""


@pytest.mark.parametrize("package", ["teleop", "estimator", "haptics"])
def test_a_ctrl_c_while_the_command_line_starts_is_one_line_and_130(package):
    done = subprocess.run([sys.executable, "-c", STARTUP.format(package=package)], capture_output=True, text=True,
                          timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (130, "", f"{package}: interrupted\n")
