"""SIGHUP (a closed terminal, an SSH drop) and repeated stop signals: the live processes stop cleanly.

The rule (docs/operating.md): a process with nothing to reload on SIGHUP stops on it as on SIGTERM
(:class:`~teleop.live.StopSignals` without ``on_hangup``; ``teleop demo`` and the batch commands take it as
Ctrl-C, :func:`~teleop.clikit.sigterm_as_ctrl_c`), unless SIGHUP was ignored (``nohup``); a second stop
signal while a process closes does not cut its closing short.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path


def _script(code: str, timeout_s: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], timeout=timeout_s, capture_output=True,
                          text=True)


# In a child process each: on the old handling SIGHUP killed the process, which must not be pytest.

def test_sighup_stops_a_process_with_nothing_to_reload_as_sigterm_does():
    done = _script("""
    import os, signal
    from teleop.live import StopSignals
    previous = signal.getsignal(signal.SIGHUP)
    with StopSignals() as signals:
        os.kill(os.getpid(), signal.SIGHUP)
        assert signals.stop.wait(1.0)
    assert signal.getsignal(signal.SIGHUP) is previous
    print("stopped")
    """)
    assert done.returncode == 0 and "stopped" in done.stdout, done.stderr


def test_sighup_ignored_on_entry_stays_ignored():  # nohup
    done = _script("""
    import os, signal, time
    from teleop.clikit import sigterm_as_ctrl_c
    from teleop.live import StopSignals
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    with StopSignals() as signals:
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.05)
        assert not signals.stop.is_set()
    with sigterm_as_ctrl_c():
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.05)
    assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    print("ignored")
    """)
    assert done.returncode == 0 and "ignored" in done.stdout, done.stderr


def test_sighup_is_ctrl_c_where_sigterm_is_and_only_the_first():
    done = _script("""
    import os, signal, time
    from teleop.clikit import sigterm_as_ctrl_c
    previous = signal.getsignal(signal.SIGHUP)
    try:
        with sigterm_as_ctrl_c():
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("interrupted")
    assert signal.getsignal(signal.SIGHUP) is previous
    """)
    assert done.returncode == 0 and "interrupted" in done.stdout, done.stderr


_FAKE_SERVICES = """
    import os, signal, sys, types, argparse
    closed = []

    class Ctx:
        endpoint = "tcp://127.0.0.1:1"
        simulated = True
        def __init__(self, *a, **k): pass
        @classmethod
        def from_settings(cls, *a, **k): return cls()
        def __enter__(self): return self
        def __exit__(self, *exc):
            os.kill(os.getpid(), signal.SIGTERM)  # a second stop signal while the services close
            for _ in range(1000): pass
            closed.append(type(self).__name__)
        def close(self): self.__exit__()
        def wire_stats(self): return {}

    class Stopping(Ctx):  # a service that is sent the first stop signal while it serves
        def run(self, stop, duration_s=None):
            os.kill(os.getpid(), signal.SIGTERM)
            assert stop.wait(5)
            return Stats()
"""


def test_a_second_sigterm_while_the_node_closes_does_not_cut_its_closing_short():
    done = _script(_FAKE_SERVICES + """
    import teleop.node_cli as cli
    class Stats:
        grasps, frames = 0, 0
        def as_dict(self): return {}
    cli.Publisher = cli.Subscriber = cli.LiveTap = Ctx
    cli.RobotNode = Stopping
    parser = argparse.ArgumentParser(); cli.add_arguments(parser)
    assert cli.run(parser.parse_args([])) == 0
    print("closed", len(closed))
    """)
    assert done.returncode == 0, done.stderr
    assert "closed 4" in done.stdout and "robot node: 0 grasps" in done.stderr


def test_a_second_sigterm_while_the_renderer_closes_does_not_cut_its_closing_short():
    done = _script(_FAKE_SERVICES + """
    import haptics.service_cli as cli
    class Stats:
        estimates, finals, final_estimates, ignored = 0, [], 0, 0
        def as_dict(self): return {}
    class Display(Ctx):
        reports_written = 0
    cli.Publisher = cli.Subscriber = cli.LiveTap = Ctx
    cli.make_display = lambda rendering: Display()
    cli.HapticRenderer = lambda display, rendering: None
    cli.RendererService = Stopping
    parser = argparse.ArgumentParser(); cli.add_arguments(parser)
    assert cli.run(parser.parse_args(["--backend", "sim"])) == 0
    print("closed", len(closed))
    """)
    assert done.returncode == 0, done.stderr
    assert "closed 4" in done.stdout and "renderer: 0 estimates" in done.stderr


def test_sighup_stops_the_record_command_and_its_log_gets_its_footer(tmp_path):
    from teleop.bus.pubsub import Publisher
    from teleop.session import LogReader
    from teleop.session.logfile import END_METADATA

    path = tmp_path / "hup.mcap"
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        proc = subprocess.Popen([str(Path(sys.executable).parent / "teleop"), "record", "--out", str(path),
                                 "--endpoint", pub.endpoint, "--scene", "quick", "--flush-interval-s", "0.05"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            # The recorder is up and recording: it sets its signal handling, then creates the log and
            # subscribes (SessionRecorder.run opens it), so both say the handler is in place.
            pub.wait_for_subscriber("", timeout_s=30.0)
            deadline = time.monotonic() + 30.0
            while not path.exists():
                assert time.monotonic() < deadline and proc.poll() is None, "the recorder created no log"
                time.sleep(0.02)
            proc.send_signal(signal.SIGHUP)  # its terminal closed
            _, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, err
    reader = LogReader(path)
    list(reader.messages())  # read to the end: the footer reached, nothing damaged
    assert reader.complete and END_METADATA in reader.info().metadata


def test_the_demos_ordered_stop_is_not_cut_short_by_a_second_ctrl_c():
    from teleop.system.live_system import LiveSystem

    system = LiveSystem.__new__(LiveSystem)
    seen = []
    system.stop = lambda: seen.append(signal.getsignal(signal.SIGINT))
    before = signal.getsignal(signal.SIGINT)
    system.__exit__(KeyboardInterrupt, KeyboardInterrupt(), None)
    assert seen == [signal.SIG_IGN]  # Ctrl-C ignored while the children stop in order
    assert signal.getsignal(signal.SIGINT) is before
