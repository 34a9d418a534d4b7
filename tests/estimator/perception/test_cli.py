"""``estimator calibrate`` and ``estimator reconstruct`` end to end on real presses."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from estimator.cli import main
from teleop.settings import default_settings_path

MINI_ARGS = ["--ball-radius-mm", "2", "--mm-per-px", "0.0295"]


def run_json(capsys, *argv):
    code = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out.strip().splitlines()[-1]), err


@pytest.mark.slow
def test_calibrate_then_reconstruct_the_held_out_mini_presses(tmp_path, taxim_pack, capsys):
    pack, cal = str(taxim_pack("gelsight_mini")), str(tmp_path / "mini.npz")
    summary, err = run_json(capsys, "calibrate", "--presses", pack, *MINI_ARGS, "--out", cal)
    assert summary["n_presses"] == 24 and summary["n_train"] == 12
    assert summary["circles"] == "recorded" and summary["image_shape"] == [480, 640]
    assert "refining press circles" in err  # progress on stderr
    report, _ = run_json(capsys, "reconstruct", "--presses", pack, "--calibration", cal, *MINI_ARGS)
    assert report["split"] == "held_out"
    assert report["n"] == 12 and report["n_failed"] == 0
    assert sorted(p["index"] for p in report["presses"]) == list(range(1, 24, 2))
    assert abs(report["radius_mm_median"] - 2.0) < 0.1
    assert report["radius_rel_error_median"] < 0.08
    assert report["center_px_error_median"] < 10.0


@pytest.mark.slow
@pytest.mark.slow
def test_a_smoothing_calibration_says_which_models_refuse_it(tmp_path, taxim_pack, capsys):
    pack = str(taxim_pack("gelsight_mini"))
    summary, err = run_json(capsys, "calibrate", "--presses", pack, *MINI_ARGS, "--out", str(tmp_path / "s.npz"),
                            "--smoothing-px", "2")
    assert summary["smoothing_px"] == 2.0 and "smooths the colours by 2 px" in err and "refuses" in err
    _, err = run_json(capsys, "calibrate", "--presses", pack, *MINI_ARGS, "--out", str(tmp_path / "plain.npz"))
    assert "smooths the colours" not in err


@pytest.mark.slow
def test_folder_of_images_calibrates_on_detected_circles(tmp_path, gelsight_presses, capsys):
    folder = tmp_path / "presses"
    folder.mkdir()
    cv2.imwrite(str(folder / "f0.png"), gelsight_presses.reference)
    for i in range(0, 48, 3):
        cv2.imwrite(str(folder / f"press_{i:02d}.png"), gelsight_presses.images[i])
    cal = str(tmp_path / "cal.npz")
    summary, _ = run_json(capsys, "calibrate", "--presses", str(folder), *MINI_ARGS, "--out", cal)
    assert summary["circles"] == "detected" and summary["n_presses"] == 16
    report, _ = run_json(capsys, "reconstruct", "--presses", str(folder), "--calibration", cal, *MINI_ARGS)
    assert report["centers_from"] == "detected" and report["n"] == 8
    assert abs(report["radius_mm_median"] - 2.0) < 0.1


def test_settings_warp_the_raw_presses_first(tmp_path, gelsight_presses, capsys):
    settings = tmp_path / "settings.toml"
    # The taxim frames are not Wedge frames; only the plumbing is tested here: warp, mapped
    # circles, the pitch of the warped frame (0.0295 mm / 1.08 magnification).
    settings.write_text("[sensors.left]\npixel_pitch_m = 2.73e-5\n")
    pack = tmp_path / "pack.npz"
    np.savez(pack, f0=gelsight_presses.reference, imgs=gelsight_presses.images[:6],
             touch_center=gelsight_presses.centers_px[:6], touch_radius=gelsight_presses.radii_px[:6])
    cal = str(tmp_path / "cal.npz")
    summary, _ = run_json(capsys, "calibrate", "--presses", str(pack), "--ball-radius-mm", "2",
                          "--settings", str(settings), "--finger", "left", "--refine-passes", "0", "--out", cal)
    assert summary["image_shape"] == [250, 350]
    assert summary["mm_per_px"] == pytest.approx(0.0273)
    with np.load(cal) as data:
        provenance = json.loads(str(data["meta"]))["provenance"]
    assert provenance["frame"] == "warped_cropped" and provenance["sensor"]["finger"] == "left"
    report, _ = run_json(capsys, "reconstruct", "--presses", str(pack), "--calibration", cal,
                         "--ball-radius-mm", "2", "--settings", str(settings))
    assert report["split"] == "held_out" and report["n"] + report["n_failed"] == 3
    # Raw frames cannot be reconstructed with a calibration for warped ones.
    assert main(["reconstruct", "--presses", str(pack), "--calibration", cal, "--ball-radius-mm", "2"]) == 2
    assert "warp them with --settings" in capsys.readouterr().err


@pytest.mark.parametrize(("extra", "message"), [
    (["--ball-radius-mm", "2"], "pixel pitch unknown"),
    (["--mm-per-px", "0.0295"], "ball radius unknown"),
    (["--ball-radius-mm", "-2", "--mm-per-px", "0.0295"], "expected a positive number"),
    (["--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--finger", "left"], "--finger needs --settings"),
    (["--ball-radius-mm", "0.5", "--mm-per-px", "0.0295"], "press 0's recorded contact radius"),
    (["--ball-radius-mm", "0.5", "--mm-per-px", "0.0295"], "check --ball-radius-mm and --mm-per-px"),
    (["--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--tiles", "250", "350"],
     "--tiles 250 350: expected 1 to 7 rows and 1 to 9 columns"),
    (["--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--tiles", "0", "3"], "--tiles 0 3: expected 1 to"),
    (["--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--train-fraction", "0"], "train_fraction"),
])
def test_user_mistakes_are_one_line_errors(tmp_path, gelsight_presses, capsys, extra, message):
    pack = tmp_path / "pack.npz"
    np.savez(pack, f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2],
             touch_center=gelsight_presses.centers_px[:2], touch_radius=gelsight_presses.radii_px[:2])
    code = main(["calibrate", "--presses", str(pack), *extra, "--out", str(tmp_path / "c.npz")])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()[-1]) > 0


def test_an_existing_out_or_the_presses_are_never_replaced_unasked(tmp_path, gelsight_presses, capsys):
    pack, out = tmp_path / "pack.npz", tmp_path / "c.npz"
    np.savez(pack, f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2],
             touch_center=gelsight_presses.centers_px[:2], touch_radius=gelsight_presses.radii_px[:2])
    presses = pack.read_bytes()
    argv = ["calibrate", "--presses", str(pack), *MINI_ARGS, "--refine-passes", "0"]
    for extra in ([], ["--overwrite"]):
        assert main([*argv, "--out", str(pack), *extra]) == 2
        assert f"--out {pack}: is the --presses file" in capsys.readouterr().err
    assert pack.read_bytes() == presses
    out.write_bytes(b"a calibration in use")
    assert main([*argv, "--out", str(out)]) == 2
    assert f"--out {out}: exists already: pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"a calibration in use"
    assert main([*argv, "--out", str(out), "--overwrite"]) == 0
    with np.load(out) as data:
        assert "lut" in data.files


def test_presses_showing_no_press_are_refused_by_index(tmp_path, gelsight_presses, capsys):
    pack, out = tmp_path / "pack.npz", tmp_path / "c.npz"
    images = gelsight_presses.images[:4].copy()
    images[2] = gelsight_presses.reference  # the no-contact frame under a recorded circle
    np.savez(pack, f0=gelsight_presses.reference, imgs=images,
             touch_center=gelsight_presses.centers_px[:4], touch_radius=gelsight_presses.radii_px[:4])
    assert main(["calibrate", "--presses", str(pack), *MINI_ARGS, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{pack}: 1 of the 2 presses to calibrate on show no press inside their circle" in err
    assert "expected at least 0.1): 2 (0.000)" in err and not out.exists()


def test_stated_values_must_agree(tmp_path, gelsight_presses, capsys):
    pack = tmp_path / "pack.npz"
    np.savez(pack, f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2],
             touch_center=gelsight_presses.centers_px[:2], touch_radius=gelsight_presses.radii_px[:2],
             mm_per_px=np.array(0.03), frame=np.array("warped_cropped"))
    code = main(["calibrate", "--presses", str(pack), "--ball-radius-mm", "2", "--mm-per-px", "0.0295",
                 "--out", str(tmp_path / "c.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "give --settings" in err
    assert f"--settings {default_settings_path()}" in err  # says how to name the shipped sensors
    np.savez(pack, f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2],
             touch_center=gelsight_presses.centers_px[:2], touch_radius=gelsight_presses.radii_px[:2],
             mm_per_px=np.array(0.03))
    code = main(["calibrate", "--presses", str(pack), "--ball-radius-mm", "2", "--mm-per-px", "0.0295",
                 "--out", str(tmp_path / "c.npz")])
    assert code == 2 and "0.0295 but" in capsys.readouterr().err


def test_help_explains_every_option(capsys):
    for command, own in (("calibrate", ("--out", "--train-fraction", "--bins", "--tiles", "--refine-passes",
                                       "--flat-weight")),
                         ("reconstruct", ("--calibration", "--all"))):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = capsys.readouterr().out
        for option in ("--presses", "--ball-radius-mm", "--mm-per-px", "--settings", "--finger", "--circles",
                       "--json", *own):
            assert option in text


@pytest.mark.slow
@pytest.mark.parametrize("finger", ["left", "right"])
def test_simulated_presses_calibrate_like_real_ones(tmp_path, capsys, finger):
    """The contract with ``teleop simulate-presses``: raw frames, circles and pitch in the warped grid."""
    from teleop.cli import main as teleop_main
    from teleop.settings import default_settings_path

    pack, cal = str(tmp_path / "sim.npz"), str(tmp_path / "cal.npz")
    assert teleop_main(["simulate-presses", "--out", pack, "--finger", finger, "--n", "24", "--seed", "3"]) == 0
    capsys.readouterr()
    # Ball radius and pitch come from the file; the right finger's gel has markers (from the settings).
    common = ["--presses", pack, "--settings", str(default_settings_path()), "--finger", finger]
    summary, _ = run_json(capsys, "calibrate", *common, "--out", cal)
    assert summary["image_shape"] == [250, 350] and summary["markers"] == (finger == "right")
    report, _ = run_json(capsys, "reconstruct", *common, "--calibration", cal)
    assert report["n"] == 12 and report["n_failed"] == 0
    # Measured here (24 presses, seed 3): left 2.6% / 0.21 px, right (markers masked) 4.6% / 0.28 px;
    # with 48 presses (seed 0): 2.0% / 0.12 px and 2.8% / 0.33 px.
    assert report["radius_rel_error_median"] < (0.05 if finger == "left" else 0.08)
    assert report["center_px_error_median"] < 1.0
