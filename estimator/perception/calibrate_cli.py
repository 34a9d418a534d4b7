"""``estimator calibrate``: fit a sensor's colour-to-gradient calibration from ball presses.

Presses come from a taxim-style dataPack ``.npz`` (``f0``, ``imgs``,
``touch_center``, ``touch_radius``; optional ``frame``, ``mm_per_px``,
``ball_radius_mm``) or a folder of images with one no-contact frame named
``f0*``, ``ref*`` or ``background*`` (press circles are then detected).
With ``--capture`` the presses are first captured live from the sensor's
camera into the folder ``--presses``, guided press by press in the terminal
(:mod:`estimator.perception.capture`).
A deterministic share of the presses (``--train-fraction``) is used; the
rest are left for ``estimator reconstruct`` to check the result on.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from estimator.errors import CalibrationError
from estimator.perception.calibration_fit import (
    DEFAULT_FLAT_WEIGHT,
    DEFAULT_SMOOTHING_PX,
    fit_calibration,
)
from estimator.perception.capture import add_capture_arguments, capture_to_folder
from estimator.perception.markers import detect_markers
from estimator.perception.press_circles import VISIBLE_CHANGE, change_inside_circle, clipped_presses
from estimator.perception.presses import PressSet, load_presses, split_presses
from teleop.clikit import output_file
from teleop.record import software_version
from teleop.settings import SensorSettings, default_settings_path, load_settings

# Two stated values of one quantity (pixel pitch, ball radius) must agree this closely.
AGREEMENT = 0.01


def add_press_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``calibrate`` and ``reconstruct``: the presses and their geometry."""
    parser.add_argument(
        "--presses", required=True, metavar="PATH",
        help="taxim-style dataPack .npz (f0, imgs, touch_center, touch_radius[, frame, mm_per_px, "
             "ball_radius_mm]) or a folder of press images plus one no-contact f0*/ref*/background* image",
    )
    parser.add_argument(
        "--ball-radius-mm", type=float, metavar="R",
        help="radius of the pressed ball in mm (default: the file's ball_radius_mm)",
    )
    parser.add_argument(
        "--mm-per-px", type=float, metavar="P",
        help="gel surface per pixel of the images used, in mm (default: the file's mm_per_px, else the "
             "sensor's pixel_pitch_m when --settings warps the images)",
    )
    parser.add_argument(
        "--settings", metavar="FILE",
        help="settings TOML: warp and crop the raw images with this sensor's corners first (without it the "
             "images are used as they are: no shipped sensor's corners are assumed)",
    )
    parser.add_argument(
        "--finger", metavar="F",
        help="sensor to use from --settings (default: the settings' sensing.finger)",
    )
    parser.add_argument(
        "--circles", choices=("auto", "recorded", "detected"), default="auto",
        help="press circles: the file's recorded annotations, or detected from the images "
             "(auto: recorded when the file has them)",
    )
    parser.add_argument(
        "--markers", action=argparse.BooleanOptionalAction, default=None,
        help="the gel carries marker dots: detect and inpaint them (default: the sensor's markers "
             "setting with --settings, else no)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object on the last stdout line")


def _agreeing(name: str, candidates: list[tuple[str, float | None]]) -> float | None:
    """The first stated value; all stated values must agree within AGREEMENT."""
    stated = [(source, value) for source, value in candidates if value is not None]
    for source, value in stated:
        if not (math.isfinite(value) and value > 0):
            raise CalibrationError(f"{name} from {source} = {value!r}: expected a positive number")
    for source, value in stated[1:]:
        if abs(value - stated[0][1]) > AGREEMENT * stated[0][1]:
            raise CalibrationError(
                f"{name}: {stated[0][0]} says {stated[0][1]:.6g} but {source} says {value:.6g}"
            )
    return stated[0][1] if stated else None


def chosen_sensor(args: argparse.Namespace) -> SensorSettings | None:
    """The sensor ``--settings`` and ``--finger`` name (the settings' sensing.finger by default), or None
    without --settings. Raises CalibrationError for --finger without --settings."""
    if args.settings:
        settings = load_settings(args.settings)
        return settings.sensor(args.finger or settings.sensing.finger)
    if args.finger:
        raise CalibrationError("--finger needs --settings (the file that describes the sensor)")
    return None


def prepare_presses(
    args: argparse.Namespace, *, stated_mm_per_px: tuple[str, float] | None = None,
) -> tuple[PressSet, float, float, dict]:
    """Load the presses named by the shared options, in the frame they will be used in.

    ``stated_mm_per_px`` is one more ``(source, value)`` statement of the pixel
    pitch (a calibration's) that the others must agree with. Returns the press
    set, the pixel pitch (m), the ball radius (m) and a JSON-able record of
    the choices made.
    """
    presses = load_presses(args.presses, progress=True)
    detect = args.circles == "detected" or (args.circles == "auto" and presses.circles != "recorded")
    if not detect and presses.circles != "recorded":
        raise CalibrationError(f"--circles recorded: {args.presses} records no press circles")
    sensor = chosen_sensor(args)
    if sensor is not None:
        presses = presses.in_sensor_frame(sensor, progress=True)
    elif presses.frame == "warped_cropped":
        # Not defaulted to the shipped settings: the calibration would name the shipped sensor (and the
        # settings' finger) as the one that took the presses, and raw presses would be warped by its corners.
        raise CalibrationError(
            f"{args.presses}: its press circles and pixel pitch are for the warped-and-cropped frame; "
            "give --settings (and --finger) of the sensor that took them so the images are warped to match "
            f"(the shipped simulated sensors: --settings {default_settings_path()})"
        )
    pitch_mm = _agreeing("mm per px", [
        ("--mm-per-px", args.mm_per_px),
        (f"{args.presses} (mm_per_px)", presses.mm_per_px),
        ("--settings (pixel_pitch_m)", sensor.pixel_pitch_m * 1e3 if sensor else None),
        stated_mm_per_px or ("", None),
    ])
    if pitch_mm is None:
        raise CalibrationError("pixel pitch unknown: give --mm-per-px (the presses do not state it)")
    ball_mm = _agreeing("ball radius (mm)", [
        ("--ball-radius-mm", args.ball_radius_mm),
        (f"{args.presses} (ball_radius_mm)", presses.ball_radius_mm),
    ])
    if ball_mm is None:
        raise CalibrationError("ball radius unknown: give --ball-radius-mm (the presses do not state it)")
    if detect:
        # A contact circle is smaller than the ball; cap the seeds below it.
        presses = presses.with_detected_circles(max_radius_px=0.9 * ball_mm / pitch_mm, progress=True)
    else:
        too_big = np.flatnonzero(presses.radii_px >= ball_mm / pitch_mm)
        if too_big.size:
            i = int(too_big[0])
            raise CalibrationError(
                f"{args.presses}: press {i}'s recorded contact radius of {presses.radii_px[i]:.1f} px (and "
                f"{too_big.size - 1} more) is not smaller than the ball's {ball_mm / pitch_mm:.1f} px "
                f"({ball_mm:g} mm at {pitch_mm:g} mm/px): check --ball-radius-mm and --mm-per-px (or the "
                "file's ball_radius_mm and mm_per_px)"
            )
    record = {
        "presses": str(args.presses),
        "presses_sha256": presses.sha256,
        "n_presses": len(presses),
        "frame": presses.frame,
        "circles": presses.circles,
        "markers": bool(args.markers if args.markers is not None else sensor is not None and sensor.markers),
        "sensor": None if sensor is None else {
            "finger": sensor.finger, "model": sensor.model, "serial": sensor.serial,
        },
    }
    return presses, pitch_mm * 1e-3, ball_mm * 1e-3, record


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_press_arguments(parser)
    parser.add_argument("--out", required=True, metavar="CAL", help="calibration file to write (.npz)")
    parser.add_argument(
        "--overwrite", action="store_true",
        help="replace an existing --out (else it is refused: a calibration in use would be lost); "
             "--out is never the --presses file",
    )
    parser.add_argument(
        "--train-fraction", type=float, default=0.5,
        help="share of the presses to calibrate on, spread evenly (0.5: every other press); "
             "recorded in the file so `estimator reconstruct` checks the rest",
    )
    add_capture_arguments(parser)
    parser.add_argument("--bins", type=int, default=48, help="bins per colour channel of the lookup table")
    parser.add_argument(
        "--tiles", type=int, nargs=2, default=(3, 3), metavar=("ROWS", "COLS"),
        help="position tiles with a table each (light falls differently across the pad); each tile spans at "
             "least the ball's radius (default: 3 3)",
    )
    parser.add_argument(
        "--refine-passes", type=int, default=1,
        help="times to re-measure the press circles with the fitted table and refit; 0 uses them as given",
    )
    parser.add_argument(
        "--flat-weight", type=_flat_weight, default=DEFAULT_FLAT_WEIGHT, metavar="W",
        help="total weight of the flat-gel pixels relative to the on-ball pixels in each table bin's "
             f"mean (default {DEFAULT_FLAT_WEIGHT:g}); 'none' counts every flat pixel once, so the "
             "mostly-flat calibration set pulls small slopes towards zero",
    )
    parser.add_argument(
        "--smoothing-px", type=float, default=DEFAULT_SMOOTHING_PX, metavar="S",
        help="Gaussian sigma (pixels of the warped image) the frames are smoothed by before their colour "
             "change is looked up, here and at every use of the calibration, so that the small colour changes "
             "of shallow slopes stand out of the pixel noise; 0 looks up the 8-bit pixels as they are, as the "
             "shipped models were trained (2 reads broad contacts far better, but those models would need "
             "retraining on it: see estimator/perception/calibration_fit.py)",
    )


def _flat_weight(text: str) -> float | None:
    if text.strip().lower() == "none":
        return None
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number or 'none', got {text!r}")
    return value


def _checked_out(args: argparse.Namespace) -> Path:
    """``--out``, refused before any work when writing it would lose a file: the presses it is fitted
    from (even with --overwrite), or an existing file without --overwrite; its folder made, as every
    command's output file (:func:`~teleop.clikit.output_file`), or refused when it cannot be."""
    out = Path(args.out)
    if out.is_dir():
        raise CalibrationError(f"--out {out}: is a folder; expected a calibration file name (.npz)")
    if out.resolve() == Path(args.presses).resolve():
        raise CalibrationError(f"--out {out}: is the --presses file; the calibration would replace the presses "
                               "it is fitted from: give another --out")
    if out.exists() and not args.overwrite:
        raise CalibrationError(f"--out {out}: exists already: pass --overwrite to replace it, or another --out")
    # Now, not at the save: a folder that cannot be made would fail after the fit (and every capture).
    return output_file("--out", args.out)


def _check_tiles(tiles: tuple[int, int], shape: tuple[int, int], ball_px: float) -> None:
    """Refuse tiles smaller than the ball's radius: a tile's table would see no whole press, and
    each tile's table is bins**3 entries (250 x 350 tiles of 48 bins would need 72 GiB)."""
    most = tuple(max(1, int(side // ball_px)) for side in shape)
    if not all(1 <= t <= m for t, m in zip(tiles, most, strict=True)):
        raise CalibrationError(
            f"--tiles {tiles[0]} {tiles[1]}: expected 1 to {most[0]} rows and 1 to {most[1]} columns, so that each "
            f"tile of the {shape[0]}x{shape[1]} px images spans at least the ball's radius ({ball_px:.1f} px)"
        )


def _check_presses_visible(source: str, presses: PressSet, indices) -> None:
    """Refuse presses clipped over most of the image (overexposed or dark: :func:`clipped_presses`, by
    their index in the file; fit_calibration refuses a no-contact frame so clipped), and presses whose
    image does not change inside their circle (the no-contact frame again, a circle off the press):
    fitted on, they teach the table wrong colours, or that a pressed ball is flat gel."""
    if clipped := clipped_presses(presses.images[indices], indices):
        raise CalibrationError(f"{source}: {clipped}")
    blank = [(int(i), change_inside_circle(presses.images[i], presses.reference, presses.centers_px[i],
                                           presses.radii_px[i])) for i in indices]
    blank = [(i, peak) for i, peak in blank if peak < VISIBLE_CHANGE]
    if blank:
        listed = ", ".join(f"{i} ({peak:.3f})" for i, peak in blank[:5]) + (", ..." if len(blank) > 5 else "")
        raise CalibrationError(
            f"{source}: {len(blank)} of the {len(indices)} presses to calibrate on show no press inside their "
            f"circle (press index, largest relative colour change; expected at least {VISIBLE_CHANGE}): {listed}"
        )


def _captured(args: argparse.Namespace) -> None:
    """Run ``--capture``, having first refused what the fit would refuse only after every press."""
    sensor = chosen_sensor(args)
    if sensor is None:
        raise CalibrationError("--capture needs --settings: the file that names the sensor's camera")
    ball_mm = _agreeing("ball radius (mm)", [("--ball-radius-mm", args.ball_radius_mm)])
    if ball_mm is None:
        raise CalibrationError("--capture needs --ball-radius-mm: the captured images cannot state the ball's radius")
    pitch_mm = _agreeing("mm per px", [("--mm-per-px", args.mm_per_px),
                                       ("--settings (pixel_pitch_m)", sensor.pixel_pitch_m * 1e3)])
    _check_tiles(tuple(args.tiles), sensor.image_shape, ball_mm / pitch_mm)
    capture_to_folder(args, sensor)


def run(args: argparse.Namespace) -> int:
    out = _checked_out(args)
    if args.capture:
        _captured(args)
    presses, pitch_m, ball_m, record = prepare_presses(args)
    _check_tiles(tuple(args.tiles), presses.reference.shape[:2], ball_m / pitch_m)
    train = split_presses(len(presses), args.train_fraction)
    _check_presses_visible(args.presses, presses, train)
    record.update({
        "train_fraction": args.train_fraction,
        "train_indices": train.tolist(),
        "software_version": software_version(),
        "ball_radius_mm": ball_m * 1e3,
    })
    masks = None
    if record["markers"]:
        masks = [detect_markers(image, presses.reference) for image in presses.images[train]]
    calibration = fit_calibration(
        presses.reference, presses.images[train], presses.centers_px[train], presses.radii_px[train],
        ball_radius_m=ball_m, pixel_pitch_m=pitch_m, bins=args.bins, tiles=tuple(args.tiles),
        refine_passes=args.refine_passes, flat_weight=args.flat_weight, smoothing_px=args.smoothing_px,
        marker_masks=masks,
        provenance=record, progress=True,
    )
    path = calibration.save(out)
    refined = sum(calibration.provenance["circles_refined"])
    summary = {
        "out": str(path),
        "n_presses": len(presses),
        "n_train": len(train),
        "circles": presses.circles,
        "circles_refined": refined,
        "markers": record["markers"],
        "image_shape": list(calibration.image_shape),
        "mm_per_px": pitch_m * 1e3,
        "ball_radius_mm": ball_m * 1e3,
        "bins": calibration.bins,
        "smoothing_px": calibration.smoothing_px,
        "tiles": list(calibration.tiles),
    }
    print(
        f"calibrated on {len(train)} of {len(presses)} presses ({presses.circles} circles, {refined} "
        f"re-measured), {calibration.image_shape[0]}x{calibration.image_shape[1]} px at "
        f"{pitch_m * 1e3:.4f} mm/px -> {path}",
        file=sys.stderr if args.json else sys.stdout,
    )
    if calibration.smoothing_px:
        print(f"note: this calibration smooths the colours by {calibration.smoothing_px:g} px; a learned model "
              "trained on unsmoothed calibrations (the shipped ones) refuses its depth, and --method auto answers "
              "from the analytical fits", file=sys.stderr)
    if args.json:
        print(json.dumps(summary))
    return 0
