"""``teleop doctor``: is this rig ready for a session? Every configured device, the bus ports, the calibrations.

Devices (all read at once, for ``--duration-s``, at least three periods of the slowest configured
device, so that a healthy one shows its rate): the gripper's width stream, the load cell,
each finger's camera, the softness display and the operator's input device (``[operator] input``;
the keyboard is the console's own and has nothing to open). Each is opened through its configured
backend and read; the report gives

``rate_hz``
    readings per second over the span read (the display: none; it answers commands);
``latency_ms``
    how old the newest reading is when it reaches this process (receipt time minus its
    timestamp), median over the reads; the display: the round trip of a command (level 0,
    free) to its status report; the input device: the read itself (it is read on demand);
and a problem, with what to do, when a device does not open, sends nothing, reads slower than
80 % of its configured rate, stamps readings out of order or on another clock (more than 1 s
from this host's ``time.monotonic()``, the clock of every device timestamp), or a camera's
frames are not the size the settings say. Simulated devices (a backend whose class is
``simulated``, such as ``sim``) are fed one simulated grasp of the default scene's first object
while they are read.

Bus: each endpoint on this host must be free to bind (a port in use is a session still
running, or another program); an endpoint on another host must answer (a refused connection
is fine: nothing listens there before the session; port ``*`` is any free one, not probed); endpoints
off loopback need CURVE keys. Keys (``bus.keys_dir``) must load; where an endpoint is on this host they
must also serve it, as ``teleop node`` checks: the server secret certificate, and an authorised-keys
folder that holds client certificates only, one at least. The settings refuse a malformed endpoint,
and two that name one.

Calibrations: each sensor's colour calibration (present, loads, made for the sensor's image
grid; its age in days), required for the estimator's finger; and the estimator's model (its age). An
age is from the creation time the file records, else from the file's time (a copy's is the copy's); one
later than this host's clock is a warning, with no age: the clock or the file's stamp is wrong. A
calibration made for another sensor (its model, finger or serial) is a warning, saying which; the
estimator's finger holding another finger's file of these settings (a swap) is a problem. A missing
calibration whose name a shipped one has (a copied settings file's relative path) is pointed at it.

A URL's password (a ``camera_source`` with the stream server's login) shows as ``***``.

Exit status 0 when everything a session needs is right (warnings or not), 1 otherwise.
"""

from __future__ import annotations

import argparse
import errno
import json
import logging
import math
import shlex
import socket
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from haptics.settings import display_settings
from teleop.clikit import positive_number
from teleop.devices.camera import make_camera, opencv_fix
from teleop.devices.gripper import FRANKY_FIX, make_gripper
from teleop.devices.loadcell import FIXES as LOAD_CELL_FIXES
from teleop.devices.loadcell import make_load_cell
from teleop.devices.simulated import is_simulated
from teleop.endpoints import parse_endpoint
from teleop.errors import (
    BusSecurityError,
    ComplianceTeleopError,
    DeviceStalledError,
    DeviceTimeoutError,
    TeleopError,
)
from teleop.live import ENDPOINTS
from teleop.operator import FOLLOW_RATE_HZ
from teleop.redact import redacted
from teleop.rig.load_cell_calibration import load_cell_source
from teleop.settings import (
    SensorSettings,
    Settings,
    default_settings_path,
    load_settings,
    resolve_path,
    shipped_calibration_hint,
)

__all__ = ["Check", "check_calibrations", "check_devices", "check_duration", "check_endpoints", "diagnose",
           "shortest_duration_s"]

log = logging.getLogger(__name__)
RATE_TOLERANCE = 0.8  # a device reading below this fraction of its configured rate is a problem
MAX_CLOCK_OFFSET_S = 1.0  # readings stamped further than this from the host's clock are on another clock
READ_SLICE_S = 0.2  # each read waits at most this long, so a silent device is noticed
RATE_PERIODS = 3  # a rate is judged over at least this many periods of the slowest configured device
FUTURE_STAMP_S = 60.0  # a file stamped later than this ahead of the host's clock: one of them is wrong


@dataclass
class Check:
    """One line of the report: a device, a bus endpoint or a calibration file. ``warning``: something
    to look at that does not stop a session (``ok`` stays true)."""

    name: str
    ok: bool
    rate_hz: float | None = None
    latency_ms: float | None = None
    problem: str | None = None
    detail: dict[str, Any] = field(default_factory=dict)
    warning: str | None = None


# --------------------------------------------------------------------------- devices


@dataclass
class _Probe:
    """How to read one device: ``read`` returns the timestamps of what arrived (maybe none)."""

    name: str
    device: Any
    read: Callable[[], list[float]]
    expected_hz: float | None
    where: str
    fix: str
    inspect: Callable[[], str | None] | None = None  # a check of what was read, after reading


def _fixes(settings: Settings) -> dict[str, str]:
    # The devices' own open errors end with the same words (_with_fix says them once).
    return {"gripper": FRANKY_FIX if settings.gripper.backend == "franky" else "check [gripper] backend",
            "load cell": LOAD_CELL_FIXES.get(settings.load_cell.backend, "check [load_cell]"),
            "display": "check the display's USB cable and `display.vendor_id` / `display.product_id`"
            if display_settings(settings).backend == "hid" else "check [display] backend"}


def _camera_probe(settings: Settings, sensor: Any, playback: Any) -> _Probe:
    options = {"playback": playback} if is_simulated("camera", sensor.camera_backend) else {}
    camera = make_camera(sensor, **options)
    first: list[Any] = []

    def read() -> list[float]:
        try:
            frame = camera.read(timeout_s=READ_SLICE_S)
        except DeviceTimeoutError:
            return []
        if not first:
            first.append(frame)
        return [frame.t_s]

    def inspect() -> str | None:
        want = (sensor.raw_height_px, sensor.raw_width_px)
        got = first[0].image().shape[:2] if first else want
        return None if got == want else (f"frames are {got[1]}x{got[0]} px, the settings say {want[1]}x{want[0]}: set "
                                         f"raw_width_px / raw_height_px in [sensors.{sensor.finger}] or the camera's mode")

    where = sensor.camera_source or "the simulated camera"
    fix = opencv_fix(sensor.finger) if sensor.camera_backend == "opencv" else "check [sensors]"
    return _Probe(f"camera {sensor.finger}", camera, read, sensor.camera_hz, where, fix, inspect)


def _display_probe(settings: Settings, fix: str) -> _Probe:
    from haptics.devices import make_display
    from haptics.protocol import StiffnessCommand

    display = make_display(display_settings(settings))
    faults: set[str] = set()

    def read() -> list[float]:  # a command every keepalive as the renderer sends them (a long one: each slice)
        time.sleep(min(display_settings(settings).keepalive_s, READ_SLICE_S))
        sent = time.monotonic()
        display.write_command(StiffnessCommand(level=0))  # free: safe with a hand on it
        status = display.read_status(timeout_s=READ_SLICE_S)
        if status is None:
            return []
        faults.update(status.faults)
        return [sent]

    def inspect() -> str | None:
        return f"reports faults {sorted(faults)}: see the display's manual; power-cycle it" if faults else None

    where = f"the display (backend {display_settings(settings).backend!r})"
    return _Probe("display", display, read, None, where, fix, inspect)


def _input_probe(settings: Settings) -> _Probe | Check:
    from haptics.inputs import input_class, make_input
    from haptics.settings import operator_settings

    name = operator_settings(settings).input
    if input_class(name).needs_console:
        return Check(f"input {name}", True, detail={"note": "the console's own keys: nothing to open"})
    device = make_input(name, settings)

    def read() -> list[float]:
        time.sleep(1.0 / FOLLOW_RATE_HZ)  # read on demand, as often as the console does: a spin starves the others
        return [device.read(timeout_s=READ_SLICE_S).t_s]

    fix = ("to drive without it, name another in `[operator] input` (or pass `haptics operate --input`)"
           if name != "sim" else "check [operator]")
    return _Probe(f"input {name}", device, read, None, f"the {name} input", fix)


def _simulated_playback(settings: Settings) -> Any:
    """One simulated grasp to feed the ``sim`` devices, started so that its data flows now."""
    from teleop.devices.playback import GraspPlayback
    from teleop.scene import load_scene
    from teleop.sim.grasp import simulate_grasp

    obj = load_scene("default").objects[0]
    record = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(0), seed=0)[0]
    playback = GraspPlayback(record)
    first_s = min(float(s.t_s[0]) for s in (record.force_n, record.width_m, *record.frames) if len(s))
    playback.start(time.monotonic() - (first_s - playback.origin_s))
    return playback


def _gripper_probe(settings: Settings, playback: Any, fix: str) -> _Probe:
    options = {"playback": playback} if is_simulated("gripper", settings.gripper.backend) else {}
    gripper = make_gripper(settings.gripper, **options)
    where = settings.gripper.host if settings.gripper.backend == "franky" else "the simulated gripper"
    return _Probe("gripper", gripper, lambda: gripper.widths(timeout_s=READ_SLICE_S).t_s.tolist(),
                  settings.gripper.width_read_hz, where, fix)


def _load_cell_probe(settings: Settings, playback: Any, fix: str) -> _Probe:
    simulated = is_simulated("load cell", settings.load_cell.backend)
    cell = make_load_cell(settings.load_cell, **({"playback": playback} if simulated else {}))

    def read() -> list[float]:
        try:
            return cell.read(timeout_s=READ_SLICE_S).t_s.tolist()
        except (DeviceTimeoutError, DeviceStalledError):  # no reading: judged over the whole read
            return []

    where = load_cell_source(settings.load_cell).split(" (")[0]
    return _Probe("load cell", cell, read, settings.load_cell.sample_rate_hz, where, fix)


def _probes(settings: Settings) -> list[_Probe | Check]:
    """A probe per device; a Check with the problem for a device that cannot even be set up."""
    fixes = _fixes(settings)
    uses_sim = (is_simulated("gripper", settings.gripper.backend)
                or is_simulated("load cell", settings.load_cell.backend)
                or any(is_simulated("camera", s.camera_backend) for s in settings.sensors))
    playback = _simulated_playback(settings) if uses_sim else None
    builders = [
        ("gripper", lambda: _gripper_probe(settings, playback, fixes["gripper"])),
        ("load cell", lambda: _load_cell_probe(settings, playback, fixes["load cell"])),
        *((f"camera {s.finger}", lambda s=s: _camera_probe(settings, s, playback)) for s in settings.sensors),
        ("display", lambda: _display_probe(settings, fixes["display"])),
        ("input", lambda: _input_probe(settings)),
    ]
    probes: list[_Probe | Check] = []
    for name, build in builders:
        try:
            probes.append(build())
        except ComplianceTeleopError as exc:  # no backend library, no camera source, ...
            probes.append(Check(name, False, problem=f"cannot be set up: {exc}"))
    return probes


def _judge(probe: _Probe, stamps: list[float], lags: list[float], duration_s: float) -> Check:
    if not stamps:
        skipped = getattr(probe.device, "skipped", {})  # a load cell's unreadable lines, by reason
        if sum(skipped.values()):  # it sends, but nothing readable: not the cable
            return Check(probe.name, False, problem=f"no valid reading from {probe.where} within {duration_s:g} s, "
                         f"{sum(skipped.values())} unreadable skipped ({', '.join(sorted(skipped))}): check what it "
                         "sends, and for a serial cell its baud rate (`load_cell.baud`)")
        return Check(probe.name, False, problem=f"no data from {probe.where} within {duration_s:g} s: {probe.fix}")
    t = np.asarray(stamps)
    span = float(t[-1] - t[0])
    rate = (t.size - 1) / span if t.size > 1 and span > 0 and probe.expected_hz else None
    latency_ms = 1e3 * float(np.median(lags))
    detail = {"readings": int(t.size), "expected_hz": probe.expected_hz, "monotonic": bool(np.all(np.diff(t) >= 0)),
              # the least delayed reading: a stall of this process delays readings, it never stamps them off
              "host_clock": bool(abs(min(lags)) <= MAX_CLOCK_OFFSET_S)}
    problems = []
    if probe.expected_hz and (rate is None or rate < RATE_TOLERANCE * probe.expected_hz):
        problems.append(f"reads at {rate or 0:.3g} Hz, configured {probe.expected_hz:g} Hz: {probe.fix}, and that "
                        "the configured rate is what the device delivers")
    if not detail["monotonic"]:
        problems.append("timestamps go backwards: the device or its bridge restamps readings; update its firmware")
    if not detail["host_clock"]:
        problems.append(f"timestamps are {min(lags):+.3g} s from this host's monotonic clock: stamp on "
                        "arrival, or map the device clock to the host's (as the tcp load cell does)")
    if probe.inspect is not None and (found := probe.inspect()):
        problems.append(found)
    return Check(probe.name, not problems, rate, latency_ms, "; ".join(problems) or None, detail)


def _with_fix(problem: str, fix: str) -> str:
    """``problem`` and what to do, said once: a device's own error may end with it already."""
    return problem if problem.endswith(fix) else f"{problem}: {fix}"


def _run_probe(probe: _Probe | Check, duration_s: float) -> Check:
    if isinstance(probe, Check):
        return probe
    # A driver's own error (a library's OSError, say) is this device's problem, not the report's.
    try:
        probe.device.connect()
    except Exception as exc:
        return Check(probe.name, False, problem=_with_fix(f"cannot open: {_error_text(exc)}", probe.fix))
    stamps: list[float] = []
    lags: list[float] = []
    try:
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            got = probe.read()
            if got:
                lags.append(time.monotonic() - got[-1])
                stamps += got
    except Exception as exc:
        return Check(probe.name, False, problem=_with_fix(f"failed while read: {_error_text(exc)}", probe.fix))
    finally:
        try:
            probe.device.close()
        except Exception as exc:
            log.warning("%s: closing it failed: %s", probe.name, _error_text(exc))
    return _judge(probe, stamps, lags, duration_s)


def _error_text(exc: Exception) -> str:  # another library's error with its type: whose it is
    return str(exc) if isinstance(exc, ComplianceTeleopError) else f"{type(exc).__name__}: {exc}"


def shortest_duration_s(settings: Settings) -> tuple[float, str]:
    """The shortest read in which a healthy rig shows each configured rate: :data:`RATE_PERIODS`
    periods of the slowest configured device, rounded up to 10 ms (so the figure said is one a
    user can type); and that device's setting, said (``key = rate Hz``)."""
    rates = {"[gripper] width_read_hz": settings.gripper.width_read_hz,
             "[load_cell] sample_rate_hz": settings.load_cell.sample_rate_hz,
             **{f"[sensors.{s.finger}] camera_hz": s.camera_hz for s in settings.sensors}}
    slowest = min(rates, key=rates.__getitem__)
    shortest_cs = math.ceil(round(100.0 * RATE_PERIODS / rates[slowest], 9))  # round(): 3 / 10 is 0.3, not 0.31
    return shortest_cs / 100.0, f"{slowest} = {rates[slowest]:g} Hz"


def check_duration(settings: Settings, duration_s: float, *, name: str = "duration_s =") -> None:
    """Refuse a read too short to judge the configured rates (:func:`shortest_duration_s`): it
    would fail healthy devices as slow, with wrong advice.

    Raises
    ------
    TeleopError
        ``duration_s`` is shorter (named with ``name``, with the minimum and why).
    """
    shortest, slowest = shortest_duration_s(settings)
    if not duration_s >= shortest:
        raise TeleopError(f"{name} {duration_s:g}: too short to judge the devices' rates; expected at least "
                          f"{shortest:g} s, {RATE_PERIODS} periods of the slowest configured device ({slowest})")


def check_devices(settings: Settings, *, duration_s: float = 2.0) -> list[Check]:
    """Open and read every configured device at once for ``duration_s`` (at least
    :func:`shortest_duration_s`: :func:`check_duration`); one Check each."""
    check_duration(settings, duration_s)
    probes = _probes(settings)
    with ThreadPoolExecutor(max_workers=len(probes), thread_name_prefix="doctor") as pool:
        return list(pool.map(lambda p: _run_probe(p, duration_s), probes))


# --------------------------------------------------------------------------- bus and calibrations


def _endpoint_check(name: str, endpoint: str) -> Check:
    key = f"`bus.{name}`"
    parts = parse_endpoint(endpoint)  # checked when the settings loaded
    if parts.scheme != "tcp" or parts.port is None:  # ipc, inproc; "*": any free port will do (bound here)
        return Check(name, True, detail={"endpoint": endpoint, "probed": False, "here": True})
    host, port = parts.host.removeprefix("[").removesuffix("]"), parts.port
    probe = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a port in TIME_WAIT is free for the session
    here = True  # the session binds it on this host (so far as a bind here says)
    try:
        probe.bind(("0.0.0.0" if host == "*" else host, port))
        problem = None
    except socket.gaierror as exc:
        problem, here = f"host {host!r} does not resolve ({exc.strerror}): fix {key}", False
    except OSError as exc:
        here = exc.errno == errno.EADDRINUSE
        problem = (f"port {port} on {host} is in use (a session still running, or another program): stop it or "
                   f"choose another port in {key}") if here else _reach(host, port, key)
    finally:
        probe.close()
    return Check(name, problem is None, problem=problem, detail={"endpoint": endpoint, "probed": True, "here": here})


def _reach(host: str, port: int, key: str) -> str | None:
    """None when ``host`` answers on ``port`` (a refusal counts: nothing need listen before the session)."""
    try:
        socket.create_connection((host, port), timeout=1.0).close()
    except ConnectionRefusedError:
        return None
    except OSError as exc:
        return f"{host}:{port} does not answer ({exc.strerror or exc}): check the network, that host, and {key}"
    return None


def _keys_check(settings: Settings, endpoints: list[Check]) -> Check | None:
    """The CURVE keys: needed where they must be, loaded, and able to serve the endpoints bound here."""
    from teleop.bus import security

    bus = settings.bus
    try:
        keys = security.security_from_settings(bus)
        # all five: security_from_settings checks three, but the renderer and `estimator reload` refuse theirs too
        security.check_endpoints([c.detail["endpoint"] for c in endpoints], keys)
        if keys is None:
            return None
        role = "server and client" if keys.server_secret_key is not None else "client only"
        detail = {"keys_dir": str(keys.keys_dir), "role": role, "authorized_clients": None,
                  "note": f"{role}: connects to servers on other hosts"}
        if any(c.detail["here"] for c in endpoints):  # the node's own check, before it binds
            clients = security.serving_keys(keys)
            detail.update(authorized_clients=len(clients), note=f"{role}; {len(clients)} authorised client(s)")
            if not clients:
                return Check("bus keys", False, problem=(
                    f"{keys.authorized_dir} holds no client keys: no client can connect, this host's own "
                    "processes included; authorise each one's client.key with `teleop keys add`"), detail=detail)
            if keys.client_public_key.decode("ascii") not in {c.public_key for c in clients}:
                own = keys.keys_dir / f"{security.CLIENT_CERT}{security.PUBLIC_SUFFIX}"
                unauthorised = f"this host's client key {own} is not authorised in {keys.authorized_dir}"
                if all(c.detail["here"] for c in endpoints):  # every peer is this host's: they refuse each other
                    return Check("bus keys", False, problem=(
                        f"{unauthorised}, and every endpoint is bound on this host: its processes refuse each "
                        f"other; run `teleop keys add {keys.keys_dir} {own}`, then restart the servers"),
                        detail=detail)
                detail["note"] += f"; {unauthorised}: this host's own processes cannot connect to what it binds"
    except BusSecurityError as exc:  # says what to do itself
        return Check("bus keys", False, problem=str(exc))
    return Check("bus keys", True, detail=detail)


def check_endpoints(settings: Settings) -> list[Check]:
    """Each bus endpoint free (on this host) or answering (elsewhere), and CURVE keys where needed."""
    checks = [_endpoint_check(name, getattr(settings.bus, name)) for name in ENDPOINTS]
    keys = _keys_check(settings, checks)
    return checks if keys is None else [*checks, keys]


def _utc_text(t_s: float) -> str:
    """The POSIX time ``t_s`` as ISO 8601 UTC, to the second (past the year 9999: the POSIX seconds)."""
    try:
        return datetime.fromtimestamp(t_s, UTC).isoformat(timespec="seconds")
    except (OverflowError, OSError, ValueError):  # a stamp in the year 10000 in UTC, say
        return f"POSIX time {t_s:.0f} s"


def _age(created_utc: Any, path: Path) -> tuple[dict[str, float], str | None]:
    """The age of a calibration or model file: days since ``created_utc`` (ISO 8601, as calibrations
    and models record it), else since ``path`` was last written (a copied or installed file's is the
    day of the copy, not of the fit).

    Returns
    -------
    detail : dict
        ``{"age_days": days}``; empty when the file is stamped in the future.
    warning : str or None
        For a stamp more than ``FUTURE_STAMP_S`` ahead of this host's clock: the stamp, the clock, and
        that one of them is wrong (not a negative age).
    """
    try:
        created = datetime.fromisoformat(created_utc)
    except (TypeError, ValueError):
        created_s, stamp = path.stat().st_mtime, "its file time"
    else:
        created_s, stamp = (created if created.tzinfo else created.replace(tzinfo=UTC)).timestamp(), "created_utc"
    now_s = time.time()
    if created_s - now_s > FUTURE_STAMP_S:
        return {}, (f"stamped in the future ({stamp} {_utc_text(created_s)}, this host's clock "
                    f"{_utc_text(now_s)}): the clock or the file's stamp is wrong")
    return {"age_days": round(max(now_s - created_s, 0.0) / 86400.0, 1)}, None


def _calibrate_todo(sensor: SensorSettings, settings_path: Path) -> str:
    """How to make ``sensor``'s calibration: the capture of docs/rig.md (ball presses), into the file
    the settings name (or one beside them, to be named there)."""
    out = resolve_path(sensor.calibration) if sensor.calibration else settings_path.parent / f"calibration-{sensor.finger}.npz"
    # --capture needs a new folder for the presses, and the ball's radius (captured presses do not say it)
    command = ["estimator", "calibrate", "--capture", "--presses", f"runs/presses-{sensor.finger}",
               "--settings", str(settings_path), "--finger", sensor.finger, "--ball-radius-mm", "2", "--out", str(out)]
    then = "" if sensor.calibration else f', then set calibration = "{out.name}" in [sensors.{sensor.finger}]'
    todo = f"run `{shlex.join(command)}` (--ball-radius-mm: the pressed ball's radius){then}"
    hint = shipped_calibration_hint(sensor)
    return todo if hint is None else f"{hint}, or make your own: {todo}"


def check_calibrations(settings: Settings, settings_path: Path) -> list[Check]:
    """Each sensor's colour calibration and the estimator's model: present, loadable, their age."""
    from estimator.errors import EstimatorError
    from estimator.inference.infer import read_metadata
    from estimator.measurements import calibration_sensor_mismatch, check_calibration_fits
    from estimator.perception.calibration import load_calibration
    from estimator.service import resolve_model_dir

    checks = []
    for sensor in settings.sensors:
        name, needed = f"calibration {sensor.finger}", sensor.finger == settings.sensing.finger
        todo = _calibrate_todo(sensor, settings_path)
        if not sensor.calibration:
            checks.append(Check(name, not needed, problem=f"none configured: {todo}" if needed else None))
            continue
        path = resolve_path(sensor.calibration)
        detail = {"path": str(path)}
        try:
            calibration = load_calibration(path)
            check_calibration_fits(calibration, sensor)
            mismatch = calibration_sensor_mismatch(calibration, sensor)
            fix = f"name this sensor's own file in [sensors.{sensor.finger}] calibration"
            owner = next((other.finger for other in settings.sensors if other is not sensor
                          and calibration_sensor_mismatch(calibration, other) is None), None)
            # Another sensor's colours read as other slopes: on the estimator's finger, wrong moduli that
            # nothing downstream notices. The file of another sensor of this rig is a swap, a mistake: not
            # ready. One of a sensor not in these settings may be this one's twin, which a lab may use
            # knowingly (the estimator runs on it, warning): a warning, as the estimator has it.
            if mismatch and owner is not None and needed:
                checks.append(Check(name, False, problem=f"{mismatch}; it is [sensors.{owner}]'s: {fix}", detail=detail))
                continue
            age, stamp_warning = _age(calibration.provenance.get("created_utc"), path)
            warning = "; ".join(w for w in (mismatch and f"{mismatch}: {fix}", stamp_warning) if w) or None
            checks.append(Check(name, True, detail={**detail, **age}, warning=warning))
        except EstimatorError as exc:
            checks.append(Check(name, False, problem=f"{exc}: {todo}", detail=detail))
    model_dir = resolve_model_dir(None, settings)
    if model_dir is None:
        checks.append(Check("model", True, problem=None, detail={"path": None, "note": "none: analytical fits only"}))
    elif not (model_dir / "model.onnx").is_file() or not (model_dir / "metadata.json").is_file():
        checks.append(Check("model", False, problem=f"{model_dir} lacks model.onnx or metadata.json: fix "
                                                    "`estimator.model_path` or train one", detail={"path": str(model_dir)}))
    else:
        try:
            metadata = read_metadata(model_dir)[1]
        except EstimatorError as exc:
            checks.append(Check("model", False, problem=f"{exc}: fix `estimator.model_path` or train one",
                                detail={"path": str(model_dir)}))
        else:
            created = metadata.get("created_utc") if isinstance(metadata, dict) else None
            age, warning = _age(created, model_dir / "model.onnx")
            checks.append(Check("model", True, detail={"path": str(model_dir), **age}, warning=warning))
    return checks


def diagnose(settings_path: Path, *, duration_s: float = 2.0) -> dict[str, Any]:
    """The whole report as the JSON object ``--json`` prints."""
    settings = load_settings(settings_path)
    devices = check_devices(settings, duration_s=duration_s)
    endpoints = check_endpoints(settings)
    calibrations = check_calibrations(settings, settings_path)
    # Sources and device errors may quote a URL with its password: the report is printed, and shared.
    report = {name: [redacted(asdict(c)) for c in checks]
              for name, checks in (("devices", devices), ("endpoints", endpoints), ("calibrations", calibrations))}
    return {"ok": all(c.ok for c in (*devices, *endpoints, *calibrations)), "settings": str(settings_path), **report}


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.replace("``", "")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--settings", default=str(default_settings_path()), metavar="FILE",
                        help="settings TOML of the rig (default: the shipped simulated one)")
    parser.add_argument("--duration-s", type=positive_number, default=2.0, metavar="S",
                        help="how long every device is read, in seconds (default: 2.0); at least "
                             f"{RATE_PERIODS} periods of the slowest configured device, to judge its rate")
    parser.add_argument("--json", action="store_true",
                        help='print one JSON object: {"ok", "devices": [{"name", "ok", "rate_hz", "latency_ms", '
                             '"problem", "detail", "warning"}...], "endpoints": [...], "calibrations": [...]}')


def _number(value: float | None, digits: str) -> str:
    return "-" if value is None else format(value, digits)


def _table(report: dict[str, Any]) -> str:
    lines = [f"{'':18s} {'ok':4s} {'rate Hz':>16s} {'latency ms':>10s}  problem / what to do"]
    for section in ("devices", "endpoints", "calibrations"):
        for c in report[section]:
            expected = c["detail"].get("expected_hz")
            rate = _number(c["rate_hz"], ".1f") + (f" / {expected:g}" if expected and c["rate_hz"] else "")
            extra = c["detail"].get("endpoint") or c["detail"].get("note") or (
                f"{c['detail']['age_days']:g} days old" if "age_days" in c["detail"] else "")
            verdict = "NO" if not c["ok"] else "warn" if c["warning"] else "yes"
            lines.append(f"{c['name']:18s} {verdict:4s} {rate:>16s} "
                         f"{_number(c['latency_ms'], '.1f'):>10s}  {c['problem'] or c['warning'] or extra}")
    warned = any(c["warning"] for section in ("devices", "endpoints", "calibrations") for c in report[section])
    lines.append("NOT ready: fix the lines marked NO" if not report["ok"] else
                 "ready for a session; see the lines marked warn" if warned else "ready for a session")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    check_duration(load_settings(args.settings), args.duration_s, name="--duration-s")
    report = diagnose(Path(args.settings), duration_s=args.duration_s)
    print(json.dumps(report) if args.json else _table(report))
    return 0 if report["ok"] else 1
