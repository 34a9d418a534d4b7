"""``estimator calibrate --capture`` end to end: the OpenCV camera on a loopback MJPG stream of
taxim's real GelSight presses, each pressed in and released between no-contact frames."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from estimator.cli import main
from estimator.perception.capture import (
    Contact,
    PressTracker,
    find_contact,
    next_target,
    tile_name,
    tile_of,
)
from teleop.settings import SensorSettings, default_settings_path

# One press in each of the 3 x 3 tiles of the 480 x 640 frame (from taxim's touch_center), then three more.
PRESSES = (22, 19, 17, 10, 0, 15, 12, 3, 13, 5, 27, 40)
RELEASE = 3  # no-contact frames between presses
LEAD_IN = 12  # no-contact frames before the first press: the camera settles, the no-contact frame is taken


def jpeg(image: np.ndarray) -> bytes:
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def decoded(image: np.ndarray) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg(image), np.uint8), cv2.IMREAD_COLOR)


def press_stream(presses) -> list[bytes]:
    """No contact, then each press: the ball half in, fully in twice, half out, and released."""
    f0 = jpeg(presses.reference)
    stream = [f0] * LEAD_IN
    for i in PRESSES:
        half = jpeg(cv2.addWeighted(presses.reference, 0.5, presses.images[i], 0.5, 0.0))
        full = jpeg(presses.images[i])
        stream += [half, full, full, half] + [f0] * RELEASE
    return stream + [f0] * 5


def write_settings(tmp_path, url: str):
    path = tmp_path / "rig.toml"
    path.write_text(f'[sensors.left]\nmodel = "mini"\ncamera_backend = "opencv"\ncamera_source = "{url}"\n'
                    "raw_width_px = 640\nraw_height_px = 480\npixel_pitch_m = 2.95e-5\n")
    return path


def run_json(capsys, *argv):
    code = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out.strip().splitlines()[-1]), err


@pytest.mark.slow
def test_capture_guides_the_presses_saves_them_and_calibrates(tmp_path, gelsight_presses, mjpg_server, capsys):
    server = mjpg_server(press_stream(gelsight_presses), fps=30.0)
    settings, folder, cal = write_settings(tmp_path, server.url), tmp_path / "presses", tmp_path / "cal.npz"
    summary, err = run_json(capsys, "calibrate", "--capture", "--capture-presses", str(len(PRESSES)),
                            "--presses", str(folder), "--settings", str(settings), "--ball-radius-mm", "2",
                            "--out", str(cal))
    assert "press the ball near the upper-left, 12 more" in err
    assert "1 more" in err and "press 12 of 12 kept" in err
    assert summary["n_presses"] == len(PRESSES) and summary["circles"] == "detected"
    saved = sorted(p.name for p in folder.iterdir())
    assert saved == ["f0.png", *(f"press_{k:02d}.png" for k in range(len(PRESSES)))]
    # Of each press the full one is kept, not the ball half in or out: the frame as the camera sent it.
    for k in (0, 7, 11):
        kept = cv2.imread(str(folder / f"press_{k:02d}.png"))
        np.testing.assert_array_equal(kept, decoded(gelsight_presses.images[PRESSES[k]]))
    report, _ = run_json(capsys, "reconstruct", "--presses", str(folder), "--calibration", str(cal),
                         "--settings", str(settings), "--ball-radius-mm", "2")
    assert report["n"] == len(PRESSES) // 2 and report["n_failed"] == 0
    assert abs(report["radius_mm_median"] - 2.0) < 0.1  # as for presses from a folder (test_cli.py)


@pytest.mark.parametrize(("argv", "match"), [
    ([], "--capture needs --settings"),
    (["--settings", "S", "--capture-presses", "5"], "at least one press per tile"),
    (["--settings", "S", "--presses", "FULL"], "new or empty folder"),
    # Checked before the camera opens, not after every press has been captured.
    (["--settings", "S", "--tiles", "0", "3"], "--tiles 0 3: expected 1 to 7 rows and 1 to 9 columns"),
    (["--settings", "S", "--tiles", "8", "3", "--capture-presses", "24"], "--tiles 8 3: expected 1 to 7 rows"),
    (["--settings", "S", "--ball-radius-mm", "0"], "from --ball-radius-mm = 0.0: expected a positive number"),
])
def test_capture_refuses_what_it_cannot_do(tmp_path, capsys, argv, match):
    settings = write_settings(tmp_path, "http://127.0.0.1:9/?action=stream")
    full = tmp_path / "full"
    full.mkdir()
    cv2.imwrite(str(full / "f0.png"), np.zeros((4, 4, 3), np.uint8))
    argv = [str(settings) if a == "S" else str(full) if a == "FULL" else a for a in argv]
    base = ["calibrate", "--capture", "--ball-radius-mm", "2", "--out", str(tmp_path / "c.npz")]
    if "--presses" not in argv:
        base += ["--presses", str(tmp_path / "new")]
    assert main([*base, *argv]) == 2
    err = capsys.readouterr().err
    assert match in err and "camera of finger" not in err
    assert not (tmp_path / "new").exists()


def test_capture_asks_for_the_ball_radius_before_the_presses(tmp_path, capsys):
    """The saved folder cannot state the ball's radius: without --ball-radius-mm every capture is lost."""
    settings = write_settings(tmp_path, "http://127.0.0.1:9/?action=stream")
    assert main(["calibrate", "--capture", "--settings", str(settings), "--presses", str(tmp_path / "new"),
                 "--out", str(tmp_path / "c.npz")]) == 2
    err = capsys.readouterr().err
    assert "--capture needs --ball-radius-mm" in err and "camera of finger" not in err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("finger", ["left", "right"])
def test_capture_refuses_a_simulated_camera_plainly_and_at_once(tmp_path, capsys, finger, monkeypatch):
    settings = default_settings_path()  # the shipped simulated rig

    def opening(sensor):
        pytest.fail("opened the simulated camera: refused only after waiting for a frame")

    monkeypatch.setattr("estimator.perception.capture.make_camera", opening)
    assert main(["calibrate", "--capture", "--presses", str(tmp_path / "new"), "--settings", str(settings),
                 "--finger", finger, "--ball-radius-mm", "2", "--out", str(tmp_path / "c.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(
        f"estimator calibrate: error: {settings}: the camera of [sensors.{finger}] is simulated (backend 'sim'): "
        "it cannot be calibrated")
    assert f"teleop simulate-presses --settings {settings} --finger {finger} --out P.npz" in err
    assert not (tmp_path / "new").exists() and not (tmp_path / "c.npz").exists()


def test_a_contact_is_a_blob_of_change_and_not_noise_or_the_whole_gel(gelsight_presses):
    reference, press = gelsight_presses.reference, gelsight_presses.images[0]
    contact = find_contact(decoded(press), reference)
    assert contact and np.hypot(*np.subtract(contact.centre_px, gelsight_presses.centers_px[0])) < 10.0
    assert "relative colour change" in find_contact(decoded(reference), reference).reason
    brighter = cv2.convertScaleAbs(reference, alpha=1.3)
    assert "whole gel" in find_contact(brighter, reference).reason


def test_a_press_is_kept_at_its_strongest_once_released_and_a_flicker_is_not_one():
    tracker = PressTracker(min_frames=2, release_frames=2)
    frames = [np.full((2, 2, 3), k, np.uint8) for k in range(8)]
    contacts = [Contact(peak=p, centre_px=(1.0, 1.0), area_px=400.0) for p in (0.2, 0.5, 0.3)]
    none = Contact(reason="no contact")
    assert tracker.feed(frames[0], none) is None and not tracker.pressing
    assert all(tracker.feed(f, c) is None for f, c in zip(frames[1:4], contacts, strict=True))
    assert tracker.pressing and tracker.feed(frames[4], none) is None  # one quiet frame is not a release
    image, contact = tracker.feed(frames[5], none)
    assert contact.peak == 0.5 and image is frames[2] and not tracker.pressing
    assert tracker.feed(frames[6], contacts[0]) is None  # a single frame of contact: a flicker
    assert tracker.feed(frames[7], none) is None and tracker.feed(frames[7], none) is None


def test_targets_cover_every_tile_before_any_twice_and_spread_out():
    counts, last, seen = np.zeros((3, 3), int), None, []
    for _ in range(9):
        last = next_target(counts, last)
        counts[last] += 1
        seen.append(tile_name(*last, (3, 3)))
    assert counts.tolist() == [[1, 1, 1]] * 3 and seen[:2] == ["upper-left", "lower-right"]
    assert sorted(seen) == sorted(["upper-left", "upper-centre", "upper-right", "middle-left", "centre",
                                   "middle-right", "lower-left", "lower-centre", "lower-right"])


def test_a_wedge_press_counts_in_the_tile_of_its_warped_position_and_off_the_grid_in_none():
    sensor = SensorSettings()  # corners TL (46, 87) ... BR (446, 368)
    assert tile_of((100.0, 140.0), sensor, (3, 3)) == (0, 0)
    assert tile_of((250.0, 250.0), sensor, (3, 3)) == (1, 1)
    assert tile_of((400.0, 330.0), sensor, (3, 3)) == (2, 2)
    assert tile_of((60.0, 110.0), sensor, (3, 3)) is None  # on the gel, but in the crop
    assert tile_of((20.0, 20.0), sensor, (3, 3)) is None
