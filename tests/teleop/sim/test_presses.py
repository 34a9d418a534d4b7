"""Simulated ball presses in taxim's dataPack layout (teleop simulate-presses)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from teleop.cli import main
from teleop.errors import SimulationError
from teleop.settings import load_settings
from teleop.sim.camera_geometry import warp_to_grid
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import contact_radius_m, simulate_presses, sphere_press_height

N_PRESSES = 6


@pytest.fixture(scope="module")
def presses_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("presses") / "presses.npz"
    assert main(["simulate-presses", "--out", str(path), "--n", str(N_PRESSES), "--seed", "5"]) == 0
    return path


@pytest.fixture(scope="module")
def taxim_pack(taxim_calib_dir, missing_data) -> Path:
    path = taxim_calib_dir / "gelsight" / "dataPack.npz"
    if not path.is_file():
        missing_data(f"taxim ships no {path}")
    return path


def test_layout_matches_taxim(presses_file, taxim_pack):
    with np.load(presses_file, allow_pickle=False) as ours, np.load(taxim_pack, allow_pickle=False) as real:
        for key in real.files:
            assert key in ours.files, key
            assert ours[key].dtype.kind == real[key].dtype.kind, key
            assert ours[key].ndim == real[key].ndim, key
        for key in ("f0", "touch_center", "touch_radius", "img_size"):
            assert ours[key].dtype == real[key].dtype, key
        assert ours["f0"].shape == real["f0"].shape
        assert ours["imgs"].shape[1:] == real["imgs"].shape[1:]
        assert ours["imgs"].dtype == real["imgs"].dtype
        np.testing.assert_array_equal(ours["img_size"], real["img_size"])
        assert ours["imgs"].shape[0] == ours["touch_center"].shape[0] == ours["touch_radius"].shape[0]
        assert len(ours["names"]) == len(ours["imgs"]) + 1 and len(real["names"]) == len(real["imgs"]) + 1


def test_extra_keys_say_where_the_centres_live(presses_file):
    sensor = load_settings().sensor("left")
    with np.load(presses_file, allow_pickle=False) as pack:
        assert pack["imgs"].shape == (N_PRESSES, 480, 640, 3)
        assert str(pack["frame"]) == "warped_cropped" and pack["frame"].shape == ()
        assert float(pack["mm_per_px"]) == pytest.approx(sensor.pixel_pitch_m * 1e3)
        assert float(pack["ball_radius_mm"]) == 2.0
        depth_mm = pack["press_depth_mm"]
        assert ((depth_mm >= 0.3) & (depth_mm <= 1.0)).all()
        radius_px = np.sqrt(2 * 2.0 * depth_mm - depth_mm**2) / float(pack["mm_per_px"])
        np.testing.assert_array_equal(pack["touch_radius"], np.rint(radius_px))


def test_touch_centres_are_where_the_presses_are(presses_file):
    sensor = load_settings().sensor("left")
    with np.load(presses_file, allow_pickle=False) as pack:
        rest = cv2.GaussianBlur(warp_to_grid(pack["f0"], sensor).astype(np.float32), (0, 0), 1.5)
        for img, (x, y), radius in zip(pack["imgs"], pack["touch_center"], pack["touch_radius"],
                                       strict=True):
            grid = cv2.GaussianBlur(warp_to_grid(img, sensor).astype(np.float32), (0, 0), 1.5)
            change = np.abs(grid - rest).sum(axis=-1)
            ys, xs = np.nonzero(change > 20)  # well above noise and JPEG artefacts
            (cx, cy), found_radius = cv2.minEnclosingCircle(np.column_stack([xs, ys]).astype(np.float32))
            assert abs(cx - x) <= 2 and abs(cy - y) <= 2
            assert radius - 3 <= found_radius <= radius + 5


def test_json_summary_on_the_last_line(tmp_path, capsys):
    out = tmp_path / "p.npz"
    assert main(["simulate-presses", "--out", str(out), "--n", "2", "--finger", "right", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["out"] == str(out) and summary["n"] == 2 and summary["finger"] == "right"
    assert out.is_file()


def test_same_seed_same_file_contents(tmp_path):
    arrays = []
    for name in ("a.npz", "b.npz"):
        assert main(["simulate-presses", "--out", str(tmp_path / name), "--n", "2", "--seed", "9"]) == 0
        with np.load(tmp_path / name) as pack:
            arrays.append({k: pack[k] for k in pack.files})
    for key, value in arrays[0].items():
        np.testing.assert_array_equal(value, arrays[1][key])


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--depth-mm", "1.0", "3.0"], "depth range"),
        (["--depth-mm", "0.5", "0.2"], "depth range"),
        (["--ball-radius-mm", "30", "--depth-mm", "2.5", "2.9"], "does not fit"),
        (["--n", "0"], "at least one press"),
        (["--n", str(10**20)], "do not fit in memory"),
        (["--finger", "thumb"], "no sensor on finger"),
    ],
)
def test_user_mistakes_are_one_line_errors(tmp_path, capsys, argv, message):
    assert main(["simulate-presses", "--out", str(tmp_path / "x.npz"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_unwritable_output_is_named_before_anything_is_rendered(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("teleop.sim.presses_cli.simulate_presses", None)  # called, it would fail otherwise
    (tmp_path / "afile").write_text("")
    target = tmp_path / "afile" / "p.npz"
    assert main(["simulate-presses", "--out", str(target), "--n", "1"]) == 2
    assert f"--out {target}: {tmp_path / 'afile'} is not a directory" in capsys.readouterr().err
    assert main(["simulate-presses", "--out", str(tmp_path), "--n", "1"]) == 2
    assert f"--out {tmp_path}: is a folder; expected a file name" in capsys.readouterr().err


def test_an_existing_out_is_kept_unless_overwrite(tmp_path, capsys, monkeypatch):
    out = tmp_path / "p.npz"
    out.write_bytes(b"presses a calibration was fitted from")
    monkeypatch.setattr("teleop.sim.presses_cli.simulate_presses", None)  # refused before any rendering
    assert main(["simulate-presses", "--out", str(out), "--n", "1"]) == 2
    assert f"--out {out}: exists already: pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"presses a calibration was fitted from"
    monkeypatch.undo()
    assert main(["simulate-presses", "--out", str(out), "--n", "1", "--overwrite"]) == 0
    with np.load(out) as pack:
        assert len(pack["imgs"]) == 1


def test_a_negative_seed_is_refused_by_argparse(tmp_path, capsys):
    with pytest.raises(SystemExit) as raised:
        main(["simulate-presses", "--out", str(tmp_path / "x.npz"), "--seed", "-3"])
    assert raised.value.code == 2 and "'-3': expected a whole number >= 0" in capsys.readouterr().err


def test_sphere_cap_geometry():
    pitch = 0.1e-3
    height = sphere_press_height((101, 121), center_px=(60.0, 50.0), ball_radius_m=2e-3,
                                 depth_m=0.5e-3, pixel_pitch_m=pitch)
    assert height.max() == pytest.approx(0.5e-3)
    assert height[50, 60] == height.max()
    radius_px = contact_radius_m(2e-3, 0.5e-3) / pitch
    rows, cols = np.indices(height.shape)
    r = np.hypot(cols - 60, rows - 50)
    assert (height[r > radius_px + 1e-9] == 0).all() and (height[r < radius_px - 0.5] > 0).all()
    assert height[50, 70] == pytest.approx(0.5e-3 - (2e-3 - np.sqrt(4e-6 - (1e-3) ** 2)))


def test_pure_function_refuses_presses_deeper_than_the_gel():
    sensor = load_settings().sensor("left")
    camera = OpticsRenderer(sensor, sim=load_settings().simulation, rng=np.random.default_rng(0))
    with pytest.raises(SimulationError, match="deeper than the gel"):
        simulate_presses(camera, n=1, ball_radius_m=10e-3, depth_range_m=(1e-3, 4e-3),
                         rng=np.random.default_rng(0))


@pytest.mark.parametrize(("name", "message"), [
    ("prdir/", "names a folder (it ends in /); expected a file name"),
    ("p.npz/", "names a folder (it ends in /); expected a file name"),
    ("p.txt", "expected a name ending in .npz"),
], ids=["a folder to be", "an .npz folder to be", "another suffix"])
def test_an_out_that_is_no_npz_file_is_refused_before_rendering(tmp_path, capsys, monkeypatch, name, message):
    monkeypatch.setattr("teleop.sim.presses_cli.simulate_presses", None)  # called, it would fail otherwise
    value = f"{tmp_path}/{name}"
    assert main(["simulate-presses", "--out", value, "--n", "1"]) == 2
    assert f"--out {value}: {message}" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
