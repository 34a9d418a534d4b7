"""``teleop calibrate camera``: a Wedge's mirror corners from a no-contact frame, and the camera's latency from a tap.

Corners. With nothing touching the gel, the camera of ``--finger`` is read (the frames'
median after the first few, while exposure settles) and the gel's quadrilateral is found
in it (:func:`teleop.rig.gel_corners.find_gel_corners`). A PNG of the frame with the
quadrilateral and its labelled corners is written for a person to check (``--out-png``);
``sensors.<finger>.warp_corners_px`` is written when the fit holds. A flat sensor
(``model = "mini"``) has no mirror: its corners are not measured.

Latency (``--latency``). Then tap the gel, once and firmly, over the load cell, while
frames and force samples are recorded for ``--duration-s``. The camera's latency relative
to the load cell is the lag of the image change's cross-correlation with the force
(:mod:`teleop.rig.camera_latency`); it is written to ``sensors.<finger>.camera_latency_s``.

Nothing is written when a measurement is refused; the reason is printed and the exit
status is 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import cv2
import numpy as np

from teleop.clikit import positive_number
from teleop.devices.camera import CameraFrame, TactileCamera, make_camera
from teleop.devices.loadcell import LoadCell, make_load_cell
from teleop.devices.simulated import is_simulated
from teleop.errors import DeviceTimeoutError, TeleopError
from teleop.record import Samples
from teleop.rig.camera_latency import LatencyFit, image_change, measure_latency
from teleop.rig.conclude import conclude, say
from teleop.rig.gel_corners import CornerFit, draw_corners, find_gel_corners
from teleop.settings import SensorSettings, Settings, load_settings
from teleop.settings_edit import check_writable

__all__ = ["add_arguments", "no_contact_frame", "record_tap", "run"]

SETTLE_FRAMES = 5  # dropped after connecting: a USB camera's exposure settles
REFERENCE_FRAMES = 5  # their median is the no-contact frame
REST_FRAMES = 15  # spread over a tap's recording, their median is the gel at rest
READ_TIMEOUT_S = 2.0
POLL_S = 0.005  # a device with nothing queued is asked again after this long
DRAIN_S = 0.05  # the camera is read at most this long before the load cell is read again


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n", 1)[1]
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--settings", required=True, metavar="FILE",
                        help="settings TOML of the rig: the camera of [sensors.<finger>] (and with --latency the "
                             "[load_cell]) is read, and what is measured is written back into it")
    parser.add_argument("--finger", metavar="F",
                        help="the sensor to calibrate (default: the settings' sensing.finger)")
    parser.add_argument("--out-png", metavar="PNG",
                        help="where to write the no-contact frame with the found corners drawn on it "
                             "(default: <settings folder>/<settings name>-<finger>-corners.png)")
    parser.add_argument("--latency", action="store_true",
                        help="also measure the camera's latency against the load cell: tap the gel when asked")
    parser.add_argument("--duration-s", type=positive_number, default=5.0, metavar="S",
                        help="with --latency: seconds of frames and force recorded around the tap (default: 5.0)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object (corners, latency, changes) on stdout")


def no_contact_frame(camera: TactileCamera, *, settle_frames: int = SETTLE_FRAMES,
                     n_frames: int = REFERENCE_FRAMES) -> np.ndarray:
    """The camera's frame of the untouched gel: the per-pixel median of ``n_frames`` after the
    first ``settle_frames``, uint8 raw BGR (camera noise averages out, a passing flicker drops)."""
    for _ in range(settle_frames):
        camera.read(timeout_s=READ_TIMEOUT_S)
    images = [camera.read(timeout_s=READ_TIMEOUT_S).image() for _ in range(n_frames)]
    return np.median(np.stack(images), axis=0).round().astype(np.uint8)


def record_tap(camera: TactileCamera, cell: LoadCell, *, duration_s: float) -> tuple[list[CameraFrame], Samples]:
    """Every frame and force sample stamped in the next ``duration_s`` seconds (frames queued
    before are dropped). Both devices queue what they receive, so they are drained in turn."""
    start = time.monotonic()
    end = start + duration_s
    frames: list[CameraFrame] = []
    t_force: list[np.ndarray] = []
    force: list[np.ndarray] = []
    while time.monotonic() < end:
        drain_until = min(end, time.monotonic() + DRAIN_S)
        while time.monotonic() < drain_until:  # drain the camera; one never empty (fast) yields to the cell
            try:
                frame = camera.read(timeout_s=POLL_S)
            except DeviceTimeoutError:
                break
            if frame.t_s >= start:
                frames.append(frame)
        try:
            samples = cell.read(timeout_s=POLL_S)
        except DeviceTimeoutError:
            continue
        keep = samples.t_s >= start
        t_force.append(samples.t_s[keep])
        force.append(samples.value[keep])
    frames = [f for f in frames if f.t_s <= end]
    t_all = np.concatenate(t_force) if t_force else np.zeros(0)
    f_all = np.concatenate(force) if force else np.zeros(0)
    return frames, Samples(t_all[t_all <= end], f_all[t_all <= end])


def _default_png(settings_path: Path, finger: str) -> Path:
    return settings_path.with_name(f"{settings_path.stem}-{finger}-corners.png")


def _declared_size(frame: np.ndarray, sensor: SensorSettings, settings_path: Path) -> np.ndarray:
    """``frame``, refused unless it is the raw size the settings declare: corners found in a frame of
    another size lie outside the frame the warp is given, or at other pixels."""
    height, width = frame.shape[:2]
    if (height, width) != (sensor.raw_height_px, sensor.raw_width_px):
        raise TeleopError(
            f"{settings_path}: the camera of [sensors.{sensor.finger}] gives {width}x{height} px frames, but "
            f"raw_width_px x raw_height_px = {sensor.raw_width_px}x{sensor.raw_height_px}: set them to the "
            "camera's frame size (or set the camera to give that size); nothing was written"
        )
    return frame


def _corners(reference: np.ndarray, sensor: SensorSettings, png: Path) -> CornerFit:
    fit = find_gel_corners(reference, warped_size_px=(sensor.warped_width_px, sensor.warped_height_px))
    if not cv2.imwrite(str(png), draw_corners(reference, fit)):
        raise TeleopError(f"--out-png {png}: cannot write the overlay PNG there")
    if fit:
        say(f"gel corners of finger {sensor.finger!r} (TL, TR, BL, BR; raw px): {fit.as_settings()}; edges "
             f"straight to {fit.edge_rms_px:.2f} px RMS, {fit.contrast:.0f} levels above the housing")
        say(f"check them on {png}")
    return fit


def _latency(camera: TactileCamera, settings: Settings, duration_s: float) -> LatencyFit:
    with make_load_cell(settings.load_cell) as cell:
        say(f"tap the gel of finger {camera.sensor.finger!r} once, firmly, over the load cell, now "
             f"(recording {duration_s:g} s)")
        frames, force = record_tap(camera, cell, duration_s=duration_s)
    change = np.zeros(0)
    if frames:  # the gel at rest: the median of frames spread over the recording (the first may show the tap)
        rest = np.median(np.stack([f.image() for f in frames[::max(1, len(frames) // REST_FRAMES)]]), axis=0)
        change = image_change((frame.image() for frame in frames), rest)
    fit = measure_latency([f.t_s for f in frames], change, force.t_s, force.value)
    if fit:
        say(f"camera latency {fit.latency_s * 1e3:+.1f} ms against the load cell (correlation "
             f"{fit.correlation:.2f}; tap {fit.force_peak_n:.2f} N, image change {fit.change_peak:.1f} levels; "
             f"{len(frames)} frames, {len(force)} force samples)")
    return fit


def run(args: argparse.Namespace) -> int:
    path = Path(args.settings)
    settings = load_settings(path)
    sensor = settings.sensor(args.finger or settings.sensing.finger)
    camera_simulated = is_simulated("camera", sensor.camera_backend)
    if camera_simulated or (args.latency and is_simulated("load cell", settings.load_cell.backend)):
        backend = sensor.camera_backend if camera_simulated else settings.load_cell.backend
        raise TeleopError(f"{path}: the camera of [sensors.{sensor.finger}]{' or the load cell' if args.latency else ''} "
                          f"is simulated (backend {backend!r}): its constants are set, not measured; configure the real "
                          "devices (camera_backend = 'opencv' and camera_source; [load_cell] backend and port)")
    if sensor.model == "mini" and not args.latency:
        raise TeleopError(f"finger {sensor.finger!r} is a flat sensor (model = 'mini'): it has no mirror corners; "
                          "give --latency to measure its camera's latency")
    check_writable(path)  # before the camera is read: a run that cannot write its result is refused now
    key = f"sensors.{sensor.finger}"
    report: dict = {"finger": sensor.finger}
    refused: list[str] = []
    changes: dict = {}
    # Device errors name the device and its source (URL, port) already.
    with make_camera(sensor) as camera:
        if sensor.model != "mini":
            png = Path(args.out_png) if args.out_png else _default_png(path, sensor.finger)
            fit = _corners(_declared_size(no_contact_frame(camera), sensor, path), sensor, png)
            report["corners"] = {**_jsonable(fit), "overlay_png": str(png)}
            if fit:
                changes[f"{key}.warp_corners_px"] = fit.as_settings()
            else:
                refused.append(f"corners: {fit.reason}")
        if args.latency and not refused:
            fit = _latency(camera, settings, args.duration_s)
            report["latency"] = _jsonable(fit)
            if fit:
                # Frames arrive already shifted by the configured latency: what is left adds to it.
                changes[f"{key}.camera_latency_s"] = round(sensor.camera_latency_s + fit.latency_s, 4)
            else:
                refused.append(f"latency: {fit.reason}")
    return conclude("camera", path, report=report, changes=changes, refused="; ".join(refused), as_json=args.json)


def _jsonable(fit: CornerFit | LatencyFit) -> dict:
    out = {}
    for name, value in dataclasses.asdict(fit).items():
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, float) and not np.isfinite(value):
            value = None
        out[name] = value
    return out
