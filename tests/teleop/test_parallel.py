"""teleop.parallel.progress_map: in order, in this process or in workers, forked or spawned."""

from __future__ import annotations

import operator
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from teleop.parallel import progress_map


def test_one_worker_maps_in_order_here():
    assert progress_map(operator.neg, range(5), workers=1, desc="t", progress=False) == [0, -1, -2, -3, -4]


@pytest.mark.slow
@pytest.mark.parametrize("spawn", [False, True])
def test_workers_map_in_order_forked_or_spawned(spawn):
    # In a child interpreter, so that a hung pool fails on the timeout instead of hanging the run.
    script = textwrap.dedent(f"""
        import operator
        from teleop.parallel import progress_map
        if __name__ == "__main__":
            print(progress_map(operator.neg, range(40), workers=2, desc="t", progress=False, spawn={spawn}))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str([-i for i in range(40)])


@pytest.mark.slow
def test_ctrl_c_stops_the_workers_at_once(tmp_path):
    # Ctrl-C reaches the terminal's whole process group: parent and workers. The parent stops the
    # workers mid-chunk, without waiting on them and without a traceback from the pool's threads.
    script = tmp_path / "slow.py"
    script.write_text(textwrap.dedent("""
        import os, sys, time
        from teleop.parallel import progress_map

        def slow(i):
            os.write(1, f"worker {os.getpid()}\\n".encode())  # one write: workers share the pipe
            time.sleep(30)

        if __name__ == "__main__":
            try:
                progress_map(slow, range(8), workers=2, desc="t", progress=False, spawn=True)
            except KeyboardInterrupt:
                sys.exit(130)
    """))
    child = subprocess.Popen([sys.executable, str(script)], start_new_session=True, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    workers = {child.stdout.readline().split()[1] for _ in range(2)}  # both are inside a task
    os.killpg(child.pid, signal.SIGINT)
    try:
        _, err = child.communicate(timeout=10)
    finally:
        child.kill()
    assert child.returncode == 130, err  # a hang is the timeout above
    assert "Traceback" not in err
    for pid in map(int, workers):
        with pytest.raises(ProcessLookupError):  # stopped and reaped
            os.kill(pid, 0)
