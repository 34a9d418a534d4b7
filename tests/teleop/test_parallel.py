"""teleop.parallel.progress_map: in order, in this process or in workers, forked or spawned."""

from __future__ import annotations

import operator
import subprocess
import sys
import textwrap

import pytest

from teleop.parallel import progress_map


def test_one_worker_maps_in_order_here():
    assert progress_map(operator.neg, range(5), workers=1, desc="t", progress=False) == [0, -1, -2, -3, -4]


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
