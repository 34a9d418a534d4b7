"""Import the published dataset's raw layout: grasp folders to grasp records.

``<object>/grasp=<i>/`` holds ``<object>.avi`` (no-marker finger, MJPG, 640x480,
30 fps), ``<object>_markers.avi`` (marker finger), ``<object>_forces.pkl`` and
``<object>_widths.pkl`` (pickled 1-D numpy arrays, N and m, one value per frame).
Each grasp becomes one grasp record ``<out>/<object>/grasp=<i>.grasp``
(:mod:`teleop.record`). Frames keep the video's own JPEG bytes, unchanged
(``encoding="jpeg"``, quality unknown and recorded as None): no re-encoding loss and
no size growth. Frame ``k`` of both videos and the ``k``-th force and width share the
time ``k / fps`` s (one clock); the sensors' identity and warp calibration come from a
settings file (the no-marker video goes to the sensor without markers, the marker
video to the sensor with them).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from teleop.catalogue import ObjectSpec
from teleop.errors import DatasetError
from teleop.record import FrameStream, GraspRecord, Label, Provenance, Samples
from teleop.settings import GripperSettings, SensorSettings
from teleop.system.dataset_files import (
    check_forces,
    check_widths,
    find_layout_folders,
    layout_index,
    layout_member,
    load_pickled_array,
)

__all__ = [
    "RAW_FPS",
    "find_raw_grasps",
    "import_raw_grasp",
    "raw_sensors",
    "read_mjpg_packets",
]

RAW_FPS = 30.0


def read_mjpg_packets(path: str | os.PathLike[str]) -> tuple[tuple[bytes, ...], tuple[int, int, int]]:
    """The JPEG bytes of every frame of an MJPG video, unchanged, and the frame shape.

    Every frame is checked to decode (at 1/8 scale, for speed); the first is decoded in full
    for its (rows, cols, 3) shape.

    Raises
    ------
    DatasetError
        The video cannot be opened, is not MJPG, has no frames, is truncated (fewer frames
        than its header lists) or a frame does not decode; the message names the file.
    """
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    packets = []
    try:
        if not capture.isOpened():
            raise DatasetError(f"{path}: unreadable video (OpenCV's FFMPEG backend cannot open it)")
        fourcc = (int(capture.get(cv2.CAP_PROP_FOURCC)) & 0xFFFFFFFF).to_bytes(4, "little").decode("latin1")
        if fourcc.upper() != "MJPG":
            raise DatasetError(f"{path}: expected an MJPG video, got codec {fourcc!r}")
        listed = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        # Raw mode hands out the encoded packets (here: one JPEG per frame) instead of decoding.
        if not capture.set(cv2.CAP_PROP_FORMAT, -1):
            raise DatasetError(f"{path}: this OpenCV build cannot hand out MJPG frames undecoded")
        while True:
            ok, packet = capture.read()
            if not ok:
                break
            packets.append(packet.tobytes())
    finally:
        capture.release()
    if not packets:
        raise DatasetError(f"{path}: the video holds no frames")
    if listed > len(packets):
        raise DatasetError(f"{path}: truncated video: its header lists {listed} frames, {len(packets)} read")
    first = cv2.imdecode(np.frombuffer(packets[0], np.uint8), cv2.IMREAD_COLOR)
    if first is None:
        raise DatasetError(f"{path}: frame 0 is not a decodable JPEG")
    for i, packet in enumerate(packets[1:], start=1):
        if cv2.imdecode(np.frombuffer(packet, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
            raise DatasetError(f"{path}: frame {i} is not a decodable JPEG")
    return tuple(packets), first.shape


def _label(object_name: str, labels: Mapping[str, ObjectSpec]) -> Label:
    spec = labels.get(object_name)
    if spec is None:
        return Label(object_name=object_name)
    return Label(object_name, spec.modulus_pa, spec.material, spec.shape, {"source": spec.source})


def find_raw_grasps(root: str | os.PathLike[str]) -> list[Path]:
    """The ``<object>/grasp=<i>`` folders under ``root``, sorted."""
    return find_layout_folders(Path(root), "*/grasp=*", "<object>/grasp=<i>")


def raw_sensors(sensors: Sequence[SensorSettings]) -> tuple[SensorSettings, SensorSettings]:
    plain = next((s for s in sensors if not s.markers), None)
    marked = next((s for s in sensors if s.markers), None)
    if plain is None or marked is None:
        raise DatasetError(
            "the raw layout has a no-marker and a marker video per grasp: the settings need one "
            f"sensor without markers and one with (fingers: {[s.finger for s in sensors]})"
        )
    return plain, marked


def import_raw_grasp(
    grasp_dir: str | os.PathLike[str],
    *,
    sensors: Sequence[SensorSettings],
    labels: Mapping[str, ObjectSpec] | None = None,
    fps: float = RAW_FPS,
    max_width_m: float | None = None,
) -> GraspRecord:
    """One raw-layout grasp folder as a :class:`~teleop.record.GraspRecord`.

    Parameters
    ----------
    grasp_dir : path
        ``<object>/grasp=<i>``.
    sensors : sequence of SensorSettings
        Must hold a sensor without markers (gets ``<object>.avi``) and one with markers
        (gets ``<object>_markers.avi``); their raw frame size must match the videos.
    labels : mapping of object name to ObjectSpec, optional
        Ground truth; objects not in it get a label with the name alone.
    fps : float
        Frame rate, Hz: frame ``k`` and force/width sample ``k`` are at ``k / fps`` s.
    max_width_m : float, optional
        The gripper's widest opening, m (default: the default settings' ``gripper.max_width_m``);
        widths beyond it (plus :data:`~teleop.system.dataset_files.WIDTH_SLACK_M`) are refused.

    Raises
    ------
    DatasetError
        A file is missing, unreadable, unsafe or damaged, the videos, forces and widths
        do not have one length, a force is below zero (beyond load-cell noise) or a width
        outside the gripper's range; the message names the file.
    """
    grasp_dir = Path(grasp_dir)
    index = layout_index(grasp_dir, "grasp")
    name = grasp_dir.parent.name
    plain, marked = raw_sensors(sensors)
    force_path = layout_member(grasp_dir, f"{name}_forces.pkl")
    width_path = layout_member(grasp_dir, f"{name}_widths.pkl")
    force = load_pickled_array(force_path, ndim=1)
    width = load_pickled_array(width_path, ndim=1)
    check_forces(force_path, force)
    check_widths(width_path, width, GripperSettings().max_width_m if max_width_m is None else max_width_m)
    streams = []
    for sensor, video_name in ((plain, f"{name}.avi"), (marked, f"{name}_markers.avi")):
        video = layout_member(grasp_dir, video_name)
        packets, shape = read_mjpg_packets(video)
        expected = (sensor.raw_height_px, sensor.raw_width_px, 3)
        if shape != expected:
            raise DatasetError(f"{video}: frames are {shape}, sensor {sensor.finger!r} expects {expected}")
        if len(packets) != force.shape[0]:
            raise DatasetError(
                f"{video}: {len(packets)} frames but {force.shape[0]} forces in {name}_forces.pkl "
                "(expected one per frame)"
            )
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            t_s = np.arange(len(packets)) / fps
        if not (np.all(np.isfinite(t_s)) and np.all(np.diff(t_s) > 0)):
            raise DatasetError(f"{video}: fps = {fps} gives frame times that are not finite and increasing")
        streams.append(FrameStream(sensor.finger, t_s, packets, encoding="jpeg", shape=shape))
    if width.shape != force.shape:
        raise DatasetError(
            f"{grasp_dir / f'{name}_widths.pkl'}: {width.shape[0]} widths but {force.shape[0]} forces "
            "(expected one per frame)"
        )
    t_s = streams[0].t_s
    return GraspRecord(
        sensors=(plain, marked),
        frames=tuple(streams),
        force_n=Samples(t_s, force.astype(np.float64)),
        width_m=Samples(t_s, width.astype(np.float64)),
        provenance=Provenance(
            source="imported",
            model="published dataset, raw layout",
            created_utc=datetime.now(UTC).isoformat(timespec="seconds"),
            extra={"source_dir": str(grasp_dir), "grasp": index, "fps": fps},
        ),
        label=_label(name, labels or {}),
    )
