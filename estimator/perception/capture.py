"""Ball presses captured live from a sensor's camera, guided press by press (``estimator calibrate --capture``).

The gel is left untouched while the no-contact frame is taken (the median of a few
frames); then the ball is pressed where the terminal says, once per press, and lifted in
between. Each frame is compared with the no-contact frame (:func:`find_contact`: the
relative colour change the calibration bins, on a ``CONTACT_SCALE`` times smaller image):
a press is a run of at least ``min_frames`` frames with a contact blob, ended by
``release_frames`` frames without one (:class:`PressTracker`); of each, the frame of
strongest change (the ball at its deepest) is kept.

The targets are the calibration's position tiles (``--tiles``; each fits a table of its
own, so each needs presses): the next target is a tile with the fewest presses so far, the
farthest from the last press, so the presses cover the pad (:func:`next_target`). The press
landed where it landed: its tile counts, whatever the target was. A press whose centre
falls outside the sensor's image grid (a Wedge's crop) is not kept.

The presses are saved as a folder of images, ``f0.png`` (no contact) and ``press_NN.png``,
the folder layout ``estimator calibrate --presses`` reads (:func:`~estimator.perception.presses.load_presses`).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from estimator.errors import CalibrationError
from estimator.perception.press_circles import _change_magnitude
from estimator.perception.presses import IMAGE_SUFFIXES
from estimator.perception.warp import warp_points
from teleop.devices.camera import TactileCamera, make_camera
from teleop.devices.simulated import is_simulated
from teleop.errors import DeviceError
from teleop.rig.camera_calibration import READ_TIMEOUT_S, no_contact_frame
from teleop.settings import SensorSettings

__all__ = ["Contact", "PressTracker", "add_capture_arguments", "capture_presses", "capture_to_folder",
           "find_contact", "next_target", "tile_name", "tile_of"]

CONTACT_SCALE = 4  # contacts are looked for on an image this many times smaller: a frame in a few ms


@dataclass(frozen=True)
class Contact:
    """A contact blob in a frame, or (falsy) why there is none.

    Attributes
    ----------
    peak : float
        Largest relative colour change against the no-contact frame (:func:`find_contact`).
    centre_px : (float, float) or None
        Centroid ``(x, y)`` of the blob, pixels of the frame.
    area_px : float
        Its area, pixels of the frame.
    reason : str
        Empty for a contact.
    """

    peak: float = 0.0
    centre_px: tuple[float, float] | None = None
    area_px: float = 0.0
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason


def find_contact(image: np.ndarray, reference: np.ndarray, *, min_change: float = 0.1, min_area_px: float = 300.0,
                 max_area_fraction: float = 0.25) -> Contact:
    """The contact blob where a frame differs from the no-contact frame.

    The relative colour change (as :func:`~estimator.perception.press_circles.detect_press_circle`
    measures it), on both images reduced ``CONTACT_SCALE`` times, is thresholded at half its
    peak; the connected region holding the peak is the blob.

    Parameters
    ----------
    image, reference : ndarray
        uint8 BGR frames of one shape (raw camera frames).
    min_change : float
        Smallest peak relative change that counts as a contact (camera noise stays far below).
    min_area_px : float
        Smallest blob, pixels of the frame.
    max_area_fraction : float
        A larger blob, as a share of the frame, is the whole gel changing (lights, exposure,
        a moved camera), not a press.

    Returns
    -------
    Contact
        Falsy with the reason when there is no contact blob.
    """
    if image.shape != reference.shape:
        raise CalibrationError(f"image {image.shape} and no-contact frame {reference.shape} differ in shape")
    size = (image.shape[1] // CONTACT_SCALE, image.shape[0] // CONTACT_SCALE)
    small = [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in (image, reference)]
    magnitude = _change_magnitude(*small, 1.0)
    peak = float(magnitude.max())
    if peak < min_change:
        return Contact(peak=peak, reason=f"largest relative colour change {peak:.3f} < {min_change}")
    _, labels, stats, centroids = cv2.connectedComponentsWithStats((magnitude >= 0.5 * peak).astype(np.uint8))
    blob = labels.flat[int(np.argmax(magnitude))]
    area = float(stats[blob, cv2.CC_STAT_AREA]) * CONTACT_SCALE**2
    if area < min_area_px:
        return Contact(peak=peak, area_px=area, reason=f"the change covers {area:.0f} px < {min_area_px:.0f} px")
    if area > max_area_fraction * image.shape[0] * image.shape[1]:
        return Contact(peak=peak, area_px=area, reason=f"the whole gel changed ({area:.0f} px): lights or camera moved?")
    x, y = ((centroids[blob] + 0.5) * CONTACT_SCALE - 0.5).tolist()  # small pixel centres to full ones
    return Contact(peak=peak, centre_px=(x, y), area_px=area)


class PressTracker:
    """Turns frames and their contacts into presses: the frame of strongest change of each run of
    at least ``min_frames`` contact frames, handed out once ``release_frames`` frames show none."""

    def __init__(self, *, min_frames: int = 2, release_frames: int = 2):
        self.min_frames, self.release_frames = min_frames, release_frames
        self._best: tuple[np.ndarray, Contact] | None = None
        self._pressed = 0
        self._released = 0

    @property
    def pressing(self) -> bool:
        """Whether the last frames showed a contact that has not been released yet."""
        return self._pressed > 0

    def feed(self, image: np.ndarray, contact: Contact) -> tuple[np.ndarray, Contact] | None:
        """The press that ``image`` (showing ``contact``) ends, if it ends one."""
        if contact:
            self._pressed += 1
            self._released = 0
            if self._best is None or contact.peak > self._best[1].peak:
                self._best = (image, contact)
            return None
        self._released += 1
        if self._released < self.release_frames or not self._pressed:
            return None
        press = self._best if self._pressed >= self.min_frames else None  # a flicker is no press
        self._best, self._pressed = None, 0
        return press


def tile_name(row: int, col: int, tiles: tuple[int, int]) -> str:
    """Where tile (row, col) of a ``tiles`` grid lies, in words: "upper-left", ..., "centre"."""
    vertical = ("upper", "middle", "lower")[min(int(3 * (row + 0.5) / tiles[0]), 2)]
    horizontal = ("left", "centre", "right")[min(int(3 * (col + 0.5) / tiles[1]), 2)]
    return "centre" if (vertical, horizontal) == ("middle", "centre") else f"{vertical}-{horizontal}"


def next_target(counts: np.ndarray, last: tuple[int, int] | None) -> tuple[int, int]:
    """The tile to press next: one with the fewest presses (``counts``, per tile), the farthest from
    the ``last`` press's tile (the first tile when there was none)."""
    fewest = np.argwhere(counts == counts.min())
    if last is None:
        return tuple(int(v) for v in fewest[0])
    distance = np.hypot(*(fewest - np.array(last)).T)
    return tuple(int(v) for v in fewest[int(np.argmax(distance))])


def tile_of(centre_px: tuple[float, float], sensor: SensorSettings, tiles: tuple[int, int]) -> tuple[int, int] | None:
    """The tile of the sensor's image grid holding a raw-frame point, or None when it is off the grid."""
    point = np.array([centre_px], dtype=np.float64)
    x, y = (point if sensor.model == "mini" else warp_points(point, sensor))[0]
    rows, cols = sensor.image_shape
    if not (0 <= x < cols and 0 <= y < rows):
        return None
    return int(y * tiles[0] // rows), int(x * tiles[1] // cols)


def capture_presses(
    camera: TactileCamera, *, n_presses: int, tiles: tuple[int, int], press_timeout_s: float,
    say: Callable[[str], None],
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Guide ``n_presses`` ball presses on a connected ``camera`` (module notes).

    Returns
    -------
    reference, presses
        The no-contact frame and the kept frame of each press, uint8 raw BGR.

    Raises
    ------
    CalibrationError
        No press began within ``press_timeout_s`` of asking for one.
    """
    sensor = camera.sensor
    say("keep the gel untouched: taking the no-contact frame")
    reference = no_contact_frame(camera)
    counts = np.zeros(tiles, dtype=int)
    tracker, presses, last = PressTracker(), [], None
    while len(presses) < n_presses:
        target = next_target(counts, last)
        say(f"press the ball near the {tile_name(*target, tiles)}, {n_presses - len(presses)} more")
        asked = time.monotonic()
        press = None
        while press is None:
            if not tracker.pressing and time.monotonic() - asked > press_timeout_s:
                raise CalibrationError(f"no press seen within {press_timeout_s:g} s of asking for press "
                                       f"{len(presses) + 1} of {n_presses}")
            image = camera.read(timeout_s=READ_TIMEOUT_S).image()
            press = tracker.feed(image, find_contact(image, reference))
        image, contact = press
        tile = tile_of(contact.centre_px, sensor, tiles)
        x, y = contact.centre_px
        if tile is None:
            say(f"that press, at ({x:.0f}, {y:.0f}) px, is off the calibrated pad: not kept")
            continue
        presses.append(image)
        counts[tile] += 1
        last = tile
        say(f"press {len(presses)} of {n_presses} kept: at ({x:.0f}, {y:.0f}) px, {tile_name(*tile, tiles)}")
    return reference, presses


def add_capture_arguments(parser: argparse.ArgumentParser) -> None:
    """``--capture`` and its options, for ``estimator calibrate``."""
    parser.add_argument(
        "--capture", action="store_true",
        help="capture the presses live first, from the camera of --settings' sensor (--finger), into the new "
             "folder --presses (f0.png and press_NN.png); the terminal says where to press next and how many "
             "more; then fit on them (give --ball-radius-mm: images cannot state it)",
    )
    parser.add_argument("--capture-presses", type=int, default=16, metavar="N",
                        help="with --capture: presses to capture (at least one per tile of --tiles)")
    parser.add_argument("--press-timeout-s", type=float, default=120.0, metavar="S",
                        help="with --capture: give up when no press begins this long after asking")


def capture_to_folder(args: argparse.Namespace, sensor: SensorSettings) -> Path:
    """Run ``--capture``: capture the presses from ``sensor``'s camera into the folder ``--presses``."""
    tiles = tuple(args.tiles)
    if args.capture_presses < tiles[0] * tiles[1]:
        raise CalibrationError(f"--capture-presses {args.capture_presses}: at least one press per tile of --tiles "
                               f"{tiles[0]} {tiles[1]} is needed ({tiles[0] * tiles[1]})")
    folder = Path(args.presses)
    if folder.exists() and (not folder.is_dir() or any(p.suffix.lower() in IMAGE_SUFFIXES for p in folder.iterdir())):
        raise CalibrationError(f"--presses {folder}: with --capture, a new or empty folder to save the presses in")
    # A simulated camera only plays grasps back: no ball can be pressed on it, and waiting for its frames
    # would end in a vague timeout. Worded as `teleop calibrate camera` refuses it (teleop/rig/camera_calibration.py).
    if is_simulated("camera", sensor.camera_backend):
        # quoted: the command is to be pasted into a shell, and a settings path may hold spaces
        simulate = shlex.join(["teleop", "simulate-presses", "--settings", str(args.settings),
                               "--finger", sensor.finger])
        raise CalibrationError(
            f"{args.settings}: the camera of [sensors.{sensor.finger}] is simulated (backend "
            f"{sensor.camera_backend!r}): it cannot be "
            f"calibrated by pressing a ball on it; simulate the presses instead ({simulate} --out P.npz, then "
            "--presses P.npz without --capture), or "
            "configure the real camera (camera_backend = 'opencv' and camera_source)")
    try:
        with make_camera(sensor) as camera:
            reference, presses = capture_presses(
                camera, n_presses=args.capture_presses, tiles=tiles, press_timeout_s=args.press_timeout_s,
                say=lambda text: print(text, file=sys.stderr, flush=True))
    except DeviceError as exc:
        raise CalibrationError(f"camera of finger {sensor.finger!r} ({args.settings}): {exc}") from exc
    folder.mkdir(parents=True, exist_ok=True)
    for name, image in [("f0.png", reference), *((f"press_{i:02d}.png", im) for i, im in enumerate(presses))]:
        if not cv2.imwrite(str(folder / name), image):
            raise CalibrationError(f"cannot write {folder / name}")
    print(f"captured {len(presses)} presses into {folder}", file=sys.stderr, flush=True)
    return folder
