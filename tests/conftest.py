"""Fixtures shared by the whole suite."""

from __future__ import annotations

import http.server
import importlib.util
import os
import signal
import socketserver
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import pytest
from support.extras import TRAIN_MODULES

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"

# A suite started in the background of a shell without job control inherits Ctrl-C ignored, and so
# would every process the tests start: the tests of what a Ctrl-C does would see nothing happen.
# Handled here, it is back to its default in those processes (an exec keeps only ignored signals).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


# What needs an extra that `make check` does not install is marked with it (check leaves those tests out):
# the tests using these fixtures, and the modules that import the train extra (torch) at their top, which
# are not collected without it.
_EXTRA_FIXTURES = {"trained_model": "train", "cnn_model": "train", "marker_model": "train",
                   "franky_sim_robot": "robot_sim"}
collect_ignore = [] if importlib.util.find_spec("torch") else sorted(TRAIN_MODULES)

# The tests that use one of these session fixtures go to one pytest-xdist worker (``--dist loadgroup``),
# so the seconds it takes (a demo run, a calibration fit on real presses) are spent once, not per worker.
_SHARED_FIXTURE_GROUPS = {"quick_demo_script": "quick_demo", "quick_demo_sim": "quick_demo",
                          "gelsight_calibration": "gelsight_calibration", "mini_calibration": "mini_calibration"}


def pytest_collection_modifyitems(items) -> None:
    tests = Path(__file__).parent
    for item in items:
        markers = {_EXTRA_FIXTURES[name] for name in _EXTRA_FIXTURES.keys() & set(getattr(item, "fixturenames", ()))}
        if item.path.relative_to(tests).as_posix() in TRAIN_MODULES:
            markers.add("train")
        for marker in markers:
            item.add_marker(marker)
        group = next((_SHARED_FIXTURE_GROUPS[name] for name in getattr(item, "fixturenames", ())
                      if name in _SHARED_FIXTURE_GROUPS), None)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
    # Modules holding a long test run first, each whole (its module fixtures set up once): collected last
    # (tests/test_*.py, the retraining loop's 50 s among them), one kept a worker busy after the other ended.
    heavy = {item.path for item in items if item.get_closest_marker("slow") or item.get_closest_marker("train")}
    items.sort(key=lambda item: item.path not in heavy)


def _missing(what: str) -> None:
    """Skip a test whose reference data is missing; in CI (``CI=true``) fail it: there the data
    must be present, and a silently skipped accuracy check would pass for a green run."""
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{what} (CI=true: the reference data must be present)")
    pytest.skip(what)


@pytest.fixture(scope="session")
def missing_data():
    """``missing_data(what)``: skip for missing reference data or shipped files; fail in CI."""
    return _missing


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The reference folder beside the project (``../shared``), read-only."""
    if not (SHARED / "seed").is_dir():
        _missing(f"reference material not found at {SHARED}")
    return SHARED


@pytest.fixture(scope="session")
def taxim_calib_dir() -> Path:
    """taxim's folder of real GelSight recordings and measured tables (``calib/``); skips without taxim."""
    spec = importlib.util.find_spec("taxim")  # locate without importing (taxim pulls in torch)
    if spec is None or not spec.submodule_search_locations:
        _missing("taxim is not installed; its real GelSight recordings are needed")
    return Path(next(iter(spec.submodule_search_locations))) / "calib"


@pytest.fixture(scope="session")
def object_table(shared_dir: Path) -> Path:
    """The published object table CSV."""
    return shared_dir / "seed" / "dataset_objects_and_compliance.csv"


@pytest.fixture(scope="session")
def settings():
    """The shipped settings (simulated hardware); modules needing others define their own."""
    from teleop.settings import load_settings

    return load_settings()


@pytest.fixture(scope="session")
def calibration(settings, tmp_path_factory):
    """A calibration of the simulated left sensor from 16 simulated ball presses."""
    from estimator.perception.calibration import load_calibration
    from teleop.system.live_system import simulated_calibration

    return load_calibration(simulated_calibration(settings, tmp_path_factory.mktemp("cal"), n_presses=16))


class MjpgServer:
    """An MJPG-over-HTTP stream on loopback, as mjpg-streamer serves it (``/?action=stream``).

    Each connection is sent ``jpegs`` in order, one every ``1 / fps`` s: a list, or an iterable
    iterated anew per connection (one that makes each JPEG when asked serves content that
    depends on the time it is sent).
    """

    def __init__(self, jpegs: Iterable[bytes], *, fps: float, then: str = "stall"):
        self.jpegs, self.period_s, self.then = jpegs, 1.0 / fps, then
        self.done = threading.Event()
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                if not self.path.startswith("/?action=stream"):
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=boundarydonotcross")
                self.end_headers()
                try:
                    for jpeg in server.jpegs:
                        self.wfile.write(
                            b"--boundarydonotcross\r\nContent-Type: image/jpeg\r\n"
                            + f"Content-Length: {len(jpeg)}\r\n\r\n".encode()
                            + jpeg
                            + b"\r\n"
                        )
                        self.wfile.flush()
                        time.sleep(server.period_s)
                    if server.then == "stall":  # keep the connection open, send nothing
                        server.done.wait(30.0)
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def log_message(self, *args):
                pass

        self.httpd = socketserver.ThreadingTCPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/?action=stream"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.done.set()
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(scope="module")
def franky_sim_robot():
    """A franky-sim robot (MuJoCo) serving the libfranka protocol on a free loopback address; its
    ``hostname`` is the address, its ``hand_width`` the simulated hand's width (m). Per module: its
    simulation runs on in the background and slowed later tests (a console test 0.9 s -> 18 s)."""
    try:
        from franky_sim import SimulationServer
        from franky_sim.mujoco_simulator import MujocoSimulator
    except ImportError as exc:  # pragma: no cover - depends on the environment
        pytest.skip(f"franky-sim cannot be imported here: {exc}")
    with MujocoSimulator(enable_visualization=False) as sim:
        robot = sim.add_robot()
        with SimulationServer(sim) as server:
            server.run_async()
            yield robot


@pytest.fixture
def mjpg_server() -> Iterator[Callable[..., MjpgServer]]:
    servers: list[MjpgServer] = []

    def start(jpegs: Iterable[bytes], *, fps: float = 30.0, then: str = "stall") -> MjpgServer:
        servers.append(MjpgServer(jpegs, fps=fps, then=then))
        return servers[-1]

    yield start
    for server in servers:
        server.close()
