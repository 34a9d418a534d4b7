"""Published-dataset import: raw grasps, preprocessed samples, the command (its pickles:
test_dataset_pickles.py)."""

from __future__ import annotations

import json
import os
import pickle
import re
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from support.pickles import RunsCode, write_pickle

from estimator.training.samples import load_sample
from teleop import cli
from teleop.errors import DatasetError
from teleop.record import read_record
from teleop.settings import load_settings
from teleop.system.dataset import import_dataset
from teleop.system.dataset_preprocessed import import_preprocessed_sample
from teleop.system.dataset_raw import find_raw_grasps, import_raw_grasp, read_mjpg_packets

RAW_SHAPE = (480, 640, 3)
IMAGE_SHAPE = (250, 350)


# --------------------------------------------------------------------------- fixture builders


def synthetic_frames(n: int, *, markers: bool) -> list[np.ndarray]:
    """n smooth 640x480 BGR frames with a bright disc moving right; marker frames carry dots."""
    rows, cols = np.mgrid[0 : RAW_SHAPE[0], 0 : RAW_SHAPE[1]]
    base = np.stack([60 + cols * 0.1, 80 + rows * 0.1, np.full(rows.shape, 120.0)], axis=-1)
    frames = []
    for k in range(n):
        frame = base.copy()
        disc = (rows - 240) ** 2 + (cols - (200 + 60 * k)) ** 2 < 50**2
        frame[disc] = (230, 230, 230)
        if markers:
            frame[(rows % 40 < 4) & (cols % 40 < 4)] = 0
        frames.append(frame.astype(np.uint8))
    return frames


def write_mjpg(path: Path, frames: list[np.ndarray], fps: float = 30.0) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (RAW_SHAPE[1], RAW_SHAPE[0]))
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()


def make_raw_grasp(root: Path, name: str, index: int, n: int = 4) -> Path:
    folder = root / name / f"grasp={index}"
    folder.mkdir(parents=True)
    write_mjpg(folder / f"{name}.avi", synthetic_frames(n, markers=False))
    write_mjpg(folder / f"{name}_markers.avi", synthetic_frames(n, markers=True))
    write_pickle(folder / f"{name}_forces.pkl", np.linspace(0.5, 12.0, n) + index)
    write_pickle(folder / f"{name}_widths.pkl", np.linspace(0.050, 0.046, n))
    return folder


def make_preprocessed(root: Path, name: str, grasp: int, aug: int, n: int = 3, *, protocol: int = 4,
                      elastic=2.0e6, hertz=1.5e5) -> Path:
    folder = root / name / f"grasp={grasp}" / f"augmentation={aug}"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(grasp * 10 + aug)
    write_pickle(folder / "RGB.pkl", rng.normal(0, 20, (n, *IMAGE_SHAPE, 3)), protocol)
    write_pickle(folder / "depth.pkl", rng.uniform(0, 1.5, (n, *IMAGE_SHAPE)), protocol)
    write_pickle(folder / "RGB_markers.pkl", rng.normal(0, 20, (n, *IMAGE_SHAPE, 3)), protocol)
    write_pickle(folder / "depth_markers.pkl", rng.uniform(0, 1.5, (n, *IMAGE_SHAPE)), protocol)
    write_pickle(folder / "forces.pkl", np.array([2.0, 6.0, 11.0])[:n], protocol)
    write_pickle(folder / "widths.pkl", np.array([0.031, 0.030, 0.0295])[:n], protocol)
    write_pickle(folder / "elastic_estimate.pkl", elastic, protocol)
    write_pickle(folder / "hertz_estimate.pkl", hertz, protocol)
    return folder


# --------------------------------------------------------------------------- raw layout


def test_read_mjpg_packets_keeps_the_jpeg_frames(tmp_path):
    frames = synthetic_frames(3, markers=False)
    write_mjpg(tmp_path / "v.avi", frames)
    packets, shape = read_mjpg_packets(tmp_path / "v.avi")
    assert shape == RAW_SHAPE and len(packets) == 3
    for packet, frame in zip(packets, frames, strict=True):
        assert packet[:2] == b"\xff\xd8"  # a JPEG, as stored in the video
        decoded = cv2.imdecode(np.frombuffer(packet, np.uint8), cv2.IMREAD_COLOR)
        assert np.mean(np.abs(decoded.astype(float) - frame)) < 3.0


def test_a_video_whose_second_frame_does_not_decode_is_refused_naming_it(tmp_path):
    path = tmp_path / "v.avi"
    write_mjpg(path, synthetic_frames(3, markers=False))
    data = bytearray(path.read_bytes())
    first = data.find(b"\xff\xd8\xff")
    second = data.find(b"\xff\xd8\xff", first + 1)
    assert 0 <= first < second
    data[second:second + 3] = b"\x00\x00\x00"  # frame 1 is no longer a JPEG: frame 0 alone is decoded in full
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="frame 1 is not a decodable JPEG"):
        read_mjpg_packets(path)


def test_raw_grasp_becomes_a_record(tmp_path, object_table):
    src = tmp_path / "raw"
    folder = make_raw_grasp(src, "apple", 2, n=5)
    settings = load_settings()
    from teleop.catalogue import load_catalogue

    labels = {o.name: o for o in load_catalogue(object_table)}
    record = import_raw_grasp(folder, sensors=settings.sensors, labels=labels)

    assert [s.finger for s in record.sensors] == ["left", "right"]
    assert [s.markers for s in record.sensors] == [False, True]
    plain, marked = record.stream("left"), record.stream("right")
    assert len(plain) == len(marked) == 5
    assert plain.encoding == "jpeg" and plain.jpeg_quality is None and plain.shape == RAW_SHAPE
    np.testing.assert_array_equal(plain.t_s, np.arange(5) / 30.0)
    np.testing.assert_array_equal(record.force_n.t_s, plain.t_s)
    np.testing.assert_array_equal(record.force_n.value, np.linspace(0.5, 12.0, 5) + 2)
    np.testing.assert_array_equal(record.width_m.value, np.linspace(0.050, 0.046, 5))
    # The frames are the videos' own JPEG bytes, in order, each finger from its own video.
    assert plain.encoded == read_mjpg_packets(folder / "apple.avi")[0]
    assert marked.encoded == read_mjpg_packets(folder / "apple_markers.avi")[0]
    for k, expected in enumerate(synthetic_frames(5, markers=True)):
        assert np.mean(np.abs(marked.frame(k).astype(float) - expected)) < 3.0
    assert record.label.object_name == "apple"
    assert record.label.modulus_pa == pytest.approx(3.25e6)
    assert (record.label.material, record.label.shape) == ("food", "sphere")
    assert record.provenance.source == "imported"
    assert record.provenance.extra["grasp"] == 2


def test_raw_import_writes_readable_records_and_skips_bad_grasps(tmp_path, object_table):
    src, out = tmp_path / "raw", tmp_path / "out"
    make_raw_grasp(src, "apple", 0)
    make_raw_grasp(src, "apple", 1)
    make_raw_grasp(src, "not_in_table", 0)

    bad = {}
    folder = make_raw_grasp(src, "damaged_pickle", 0)
    (folder / "damaged_pickle_forces.pkl").write_bytes(b"\x80\x04\x95 truncated")
    bad["damaged_pickle"] = "damaged_pickle_forces.pkl: not a valid pickle"
    folder = make_raw_grasp(src, "unreadable_video", 0)
    (folder / "unreadable_video.avi").write_bytes(b"RIFF\x00\x00\x00\x00AVI not a video at all" * 8)
    bad["unreadable_video"] = "unreadable_video.avi: unreadable video"
    folder = make_raw_grasp(src, "missing_member", 0)
    (folder / "missing_member_widths.pkl").unlink()
    bad["missing_member"] = "missing_member_widths.pkl: missing"
    folder = make_raw_grasp(src, "mismatched", 0)
    write_pickle(folder / "mismatched_forces.pkl", np.ones(7))
    bad["mismatched"] = "4 frames but 7 forces"
    folder = make_raw_grasp(src, "short_widths", 0)
    write_pickle(folder / "short_widths_widths.pkl", np.full(3, 0.04))
    bad["short_widths"] = "3 widths but 4 forces"
    folder = make_raw_grasp(src, "truncated_video", 0, n=6)
    video = folder / "truncated_video_markers.avi"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    bad["truncated_video"] = "truncated_video_markers.avi: truncated video"
    folder = make_raw_grasp(src, "mm_widths", 0)
    write_pickle(folder / "mm_widths_widths.pkl", np.linspace(50.0, 46.0, 4))
    bad["mm_widths"] = "mm_widths_widths.pkl: widths must lie within 0 to 0.085 m"
    folder = make_raw_grasp(src, "bool_forces", 0)
    write_pickle(folder / "bool_forces_forces.pkl", np.array([True, True, False, True]))
    bad["bool_forces"] = "bool_forces_forces.pkl: expected a numeric array (integer or float), got dtype bool"
    folder = make_raw_grasp(src, "malicious", 0)
    marker = tmp_path / "pwned"
    write_pickle(folder / "malicious_widths.pkl", RunsCode(os.system, f"touch {marker}"))
    bad["malicious"] = "refused pickle global"
    (src / "bad_index" / "grasp=first").mkdir(parents=True)
    bad["bad_index"] = "grasp=<integer>"

    skipped = []
    summary = import_dataset(src, layout="raw", out=out, objects=object_table, on_skip=skipped.append)

    assert not marker.exists()
    assert len(summary.imported) == 3 and summary.labelled == 2
    assert sorted(Path(p).relative_to(out).as_posix() for p in summary.imported) == [
        "apple/grasp=0.grasp", "apple/grasp=1.grasp", "not_in_table/grasp=0.grasp"]
    assert skipped == summary.skipped and len(skipped) == len(bad)
    reasons = {Path(item.path).relative_to(src).parts[0]: item.reason for item in skipped}
    for name, expected in bad.items():
        assert expected in reasons[name], (name, reasons[name])
        assert str(src / name) in reasons[name]  # each reason names the file or folder
    unlabelled = read_record(out / "not_in_table" / "grasp=0.grasp")
    assert unlabelled.label.object_name == "not_in_table" and unlabelled.label.modulus_pa is None
    record = read_record(out / "apple" / "grasp=1.grasp")
    assert record.label.modulus_pa == pytest.approx(3.25e6)
    assert record.stream("left").encoded == read_mjpg_packets(src / "apple" / "grasp=1" / "apple.avi")[0]


def test_raw_import_needs_a_marker_and_a_plain_sensor(tmp_path):
    make_raw_grasp(tmp_path / "raw", "apple", 0, n=2)
    settings = tmp_path / "one_sensor.toml"
    settings.write_text("[sensors.left]\nmarkers = false\n")
    with pytest.raises(DatasetError, match="one sensor without markers and one with"):
        import_dataset(tmp_path / "raw", layout="raw", out=tmp_path / "out", settings=settings)


def test_import_refuses_a_source_without_the_layout(tmp_path):
    (tmp_path / "src" / "apple").mkdir(parents=True)
    with pytest.raises(DatasetError, match="not the expected layout"):
        find_raw_grasps(tmp_path / "src")
    with pytest.raises(DatasetError, match="not a directory"):
        import_dataset(tmp_path / "nowhere", layout="preprocessed", out=tmp_path / "out")
    with pytest.raises(DatasetError, match="layout 'video'"):
        import_dataset(tmp_path / "src", layout="video", out=tmp_path / "out")


def test_raw_import_refuses_records_already_in_out_unless_overwrite(tmp_path, object_table):
    first, second, out = tmp_path / "first", tmp_path / "second", tmp_path / "out"
    make_raw_grasp(first, "apple", 0, n=2)
    make_raw_grasp(second, "apple", 0, n=2)
    make_raw_grasp(second, "apple", 1, n=2)  # new: still not written when the import is refused
    assert import_dataset(first, layout="raw", out=out, objects=object_table).labelled == 1

    with pytest.raises(DatasetError) as refused:
        import_dataset(second, layout="raw", out=out)  # no --objects: it would drop the label
    message = str(refused.value)
    assert f"--out {out}" in message and "1 of this import's 2 outputs exist already" in message
    assert "apple/grasp=0.grasp" in message and "pass --overwrite" in message
    assert read_record(out / "apple" / "grasp=0.grasp").label.modulus_pa == pytest.approx(3.25e6)
    assert not (out / "apple" / "grasp=1.grasp").exists()

    summary = import_dataset(second, layout="raw", out=out, overwrite=True)
    assert len(summary.imported) == 2 and summary.labelled == 0
    assert read_record(out / "apple" / "grasp=0.grasp").label.modulus_pa is None


# --------------------------------------------------------------------------- preprocessed layout


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_preprocessed_folder_becomes_a_sample(tmp_path, object_table, protocol):
    folder = make_preprocessed(tmp_path, "apple", 3, 1, protocol=protocol)
    from teleop.catalogue import load_catalogue

    labels = {o.name: o for o in load_catalogue(object_table)}
    sample = import_preprocessed_sample(folder, labels=labels)
    rgb = pickle.loads((folder / "RGB.pkl").read_bytes())
    depth_mm = pickle.loads((folder / "depth.pkl").read_bytes())
    assert (sample.object_name, sample.grasp, sample.augmentation) == ("apple", 3, 1)
    assert sample.rgb_diff.dtype == np.float32
    np.testing.assert_array_equal(sample.rgb_diff, rgb.astype(np.float32))
    np.testing.assert_allclose(sample.depth_m, depth_mm * 1e-3, rtol=1e-6)
    assert sample.depth_markers_m.shape == (3, *IMAGE_SHAPE) and sample.has_markers
    np.testing.assert_array_equal(sample.force_n, [2.0, 6.0, 11.0])
    np.testing.assert_array_equal(sample.width_m, [0.031, 0.030, 0.0295])
    assert sample.elastic_estimate_pa == 2.0e6 and sample.hertz_estar_pa == 1.5e5
    assert sample.label_modulus_pa == pytest.approx(3.25e6)
    assert (sample.material, sample.shape) == ("food", "sphere")


def test_preprocessed_import_writes_samples_and_skips_bad_ones(tmp_path, object_table):
    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src, "apple", 0, 0)
    make_preprocessed(src, "apple", 0, 1, elastic=np.float64(np.nan), hertz=np.array([-4.0e5]))
    make_preprocessed(src, "mystery", 1, 0, elastic=np.inf)
    bad = {}
    folder = make_preprocessed(src, "frames_mismatch", 0, 0)
    write_pickle(folder / "forces.pkl", np.ones(4))
    bad["frames_mismatch"] = "forces.pkl: expected shape (3,) (forces in N, one per frame of RGB.pkl), got float64 (4,)"
    folder = make_preprocessed(src, "flat_depth", 0, 0)
    write_pickle(folder / "depth.pkl", np.zeros((3, 250)))
    bad["flat_depth"] = "depth.pkl: expected shape (3, 250, 350)"
    folder = make_preprocessed(src, "no_rgb", 0, 0)
    (folder / "RGB.pkl").unlink()
    bad["no_rgb"] = "RGB.pkl: missing"
    folder = make_preprocessed(src, "two_estimates", 0, 0)
    write_pickle(folder / "hertz_estimate.pkl", np.array([1.0, 2.0]))
    bad["two_estimates"] = "expected one number"
    folder = make_preprocessed(src, "evil", 0, 0)
    write_pickle(folder / "depth_markers.pkl", RunsCode(os.system, f"touch {tmp_path / 'pwned'}"))
    bad["evil"] = "refused pickle global"

    summary = import_dataset(src, layout="preprocessed", out=out, objects=object_table)

    assert not (tmp_path / "pwned").exists()
    assert len(summary.imported) == 3 and summary.labelled == 2
    assert summary.unavailable_estimates == 3
    reasons = {Path(s.path).relative_to(src).parts[0]: s.reason for s in summary.skipped}
    assert sorted(reasons) == sorted(bad)
    for name, expected in bad.items():
        assert expected in reasons[name] and str(src / name) in reasons[name], (name, reasons[name])
    guarded = load_sample(out / "apple" / "grasp=0" / "augmentation=1.npz")
    assert guarded.elastic_estimate_pa is None and guarded.hertz_estar_pa is None
    assert guarded.label_modulus_pa == pytest.approx(3.25e6)
    mystery = load_sample(out / "mystery" / "grasp=1" / "augmentation=0.npz")
    assert mystery.label_modulus_pa is None and mystery.elastic_estimate_pa is None
    assert mystery.hertz_estar_pa == 1.5e5


def replace_member(folder: Path, member: str, value) -> Path:
    write_pickle(folder / member, value)
    return folder


@pytest.mark.parametrize(
    ("member", "value", "expected"),
    [
        # bool is not a measurement: True would be imported as 1 N.
        ("forces.pkl", np.array([True, True, False]),
         ["forces.pkl: expected a numeric array (integer or float), got dtype bool"]),
        ("forces.pkl", np.array([-3.0, -8.0, -15.0]),
         ["forces.pkl: forces must be >= 0 N (to a 1 N tolerance", "got 3 below, the lowest -15 N"]),
        ("widths.pkl", np.array([40.0, 37.0, 34.0]),
         ["widths.pkl: widths must lie within 0 to 0.085 m (gripper.max_width_m 0.08 m", "got 34 to 40",
          "not in metres?"]),
        ("widths.pkl", np.array([0.03, -0.01, 0.02]), ["widths.pkl: widths must lie within 0 to", "got -0.01 to 0.03"]),
        ("RGB.pkl", np.zeros((3, 10, 10, 3)),
         ["RGB.pkl: expected shape (n, 250, 350, 3) (BGR difference images of the published 250x350 size), "
          "got float64 (3, 10, 10, 3)"]),
        ("depth.pkl", np.zeros((3, 100, 100)),
         ["depth.pkl: expected shape (3, 250, 350) (depth maps in mm of the published 250x350 size",
          "got float64 (3, 100, 100)"]),
        ("RGB_markers.pkl", np.zeros((3, 10, 10, 3)), ["RGB_markers.pkl: expected shape (3, 250, 350, 3)"]),
        ("depth_markers.pkl", np.zeros((3, 10, 10)), ["depth_markers.pkl: expected shape (3, 250, 350)"]),
        ("RGB.pkl", np.zeros((0, 250, 350, 3)), ["RGB.pkl: expected shape (n, 250, 350, 3)", "got float64 (0, 250"]),
        # Finite in float64, beyond float32: refused before the cast, never "non-finite".
        ("depth.pkl", np.full((3, 250, 350), 1e300),
         ["depth.pkl: expected depths within +-100 mm, got float64 (3, 250, 350) with values from 1e+300"]),
        ("RGB.pkl", np.full((3, 250, 350, 3), -1e300),
         ["RGB.pkl: expected 8-bit difference levels within +-1024, got float64 (3, 250, 350, 3)", "-1e+300"]),
        ("depth_markers.pkl", np.full((3, 250, 350), 5e38), ["depth_markers.pkl: expected depths within +-100 mm"]),
    ],
)
def test_preprocessed_import_refuses_impossible_samples(tmp_path, member, value, expected):
    src = tmp_path / "pre"
    make_preprocessed(src, "good", 0, 0)
    folder = replace_member(make_preprocessed(src, "bad", 0, 0), member, value)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no raw RuntimeWarning (an overflowing cast) either
        summary = import_dataset(src, layout="preprocessed", out=tmp_path / "out")
    assert [Path(p).relative_to(tmp_path / "out").as_posix() for p in summary.imported] == [
        "good/grasp=0/augmentation=0.npz"]
    [skipped] = summary.skipped
    assert skipped.path == str(folder)
    for part in expected:
        assert part in skipped.reason, skipped.reason
    assert str(folder / member) in skipped.reason
    # Names the file, not the sample's internal fields, and calls no finite value non-finite.
    assert not re.search(r"\b(depth_m|rgb_diff|force_n|width_m|depth_markers_m)\b|non-finite", skipped.reason)


def test_preprocessed_import_keeps_possible_edge_values(tmp_path):
    folder = make_preprocessed(tmp_path, "apple", 0, 0)
    # Load-cell noise around zero, a fully open gripper, integer forces and wide difference levels.
    replace_member(folder, "forces.pkl", np.array([-0.4, 3, 9]))
    replace_member(folder, "widths.pkl", np.array([0.084, 0.0, 0.0]))
    replace_member(folder, "RGB.pkl", np.full((3, *IMAGE_SHAPE, 3), -300.0))
    sample = import_preprocessed_sample(folder)
    np.testing.assert_array_equal(sample.force_n, [-0.4, 3.0, 9.0])
    np.testing.assert_array_equal(sample.width_m, [0.084, 0.0, 0.0])
    assert sample.rgb_diff.min() == -300.0


def test_import_widths_are_bounded_by_the_settings_gripper(tmp_path):
    src = tmp_path / "pre"
    make_preprocessed(src, "apple", 0, 0)  # widths up to 0.031 m
    narrow = tmp_path / "narrow.toml"
    narrow.write_text("[gripper]\nmax_width_m = 0.02\n")
    summary = import_dataset(src, layout="preprocessed", out=tmp_path / "out", settings=narrow)
    assert not summary.imported
    assert "widths must lie within 0 to 0.025 m (gripper.max_width_m 0.02 m" in summary.skipped[0].reason
    assert "not in metres?" not in summary.skipped[0].reason
    assert import_dataset(src, layout="preprocessed", out=tmp_path / "out").imported  # shipped: 0.08 m


def test_imported_sample_is_not_taken_for_a_damaged_record(tmp_path, capsys):
    from estimator.cli import main as estimator_main

    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src, "fake_washer_stack", 0, 0)
    import_dataset(src, layout="preprocessed", out=out)
    sample = out / "fake_washer_stack" / "grasp=0" / "augmentation=0.npz"
    assert estimator_main(["estimate", str(sample)]) != 0
    err = capsys.readouterr().err
    assert f"{sample}: this is a training sample (.npz, written by `teleop import-dataset --layout preprocessed`" in err
    assert "expected a .grasp record (`teleop import-dataset --layout raw`" in err
    assert "incomplete" not in err and "Traceback" not in err


def test_import_dataset_command_prints_no_overflow_warning(tmp_path, capsys):
    src = tmp_path / "pre"
    make_preprocessed(src, "apple", 0, 0)
    folder = replace_member(make_preprocessed(src, "huge", 0, 0), "depth.pkl", np.full((3, *IMAGE_SHAPE), 1e300))
    status = cli.main(["import-dataset", str(src), "--layout", "preprocessed", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 0
    assert f"skipped {folder}: {folder / 'depth.pkl'}: expected depths within +-100 mm" in err
    assert "RuntimeWarning" not in err and "non-finite" not in err


# --------------------------------------------------------------------------- the command


def test_import_dataset_command_json_summary(tmp_path, object_table, capsys):
    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src, "apple", 0, 0)
    folder = make_preprocessed(src, "broken", 0, 0)
    (folder / "widths.pkl").write_bytes(b"not a pickle")
    status = cli.main(["import-dataset", str(src), "--layout", "preprocessed", "--out", str(out),
                       "--objects", str(object_table), "--json"])
    captured = capsys.readouterr()
    assert status == 0
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert (summary["imported"], summary["skipped"], summary["labelled"]) == (1, 1, 1)
    assert "widths.pkl" in summary["skipped_items"][0]["reason"]
    assert f"skipped {folder}" in captured.err  # reported as it happens, on stderr


def test_import_dataset_command_fails_when_nothing_imports(tmp_path, capsys):
    src = tmp_path / "pre"
    folder = make_preprocessed(src, "broken", 0, 0)
    (folder / "RGB.pkl").unlink()
    status = cli.main(["import-dataset", str(src), "--layout", "preprocessed",
                       "--out", str(tmp_path / "out"), "--json"])
    assert status == 1
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["imported"] == 0
    status = cli.main(["import-dataset", str(tmp_path / "absent"), "--layout", "raw", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert status == 2 and "not a directory" in err and "Traceback" not in err


def test_import_dataset_command_refuses_samples_already_in_out_unless_overwrite(tmp_path, object_table, capsys):
    first, second, out = tmp_path / "first", tmp_path / "second", tmp_path / "out"
    for root in (first, second):
        for aug in range(5):
            make_preprocessed(root, "apple", 0, aug)
    command = ["import-dataset", "--layout", "preprocessed", "--out", str(out)]
    assert cli.main([*command, str(first), "--objects", str(object_table)]) == 0
    sample = out / "apple" / "grasp=0" / "augmentation=0.npz"
    before = sample.read_bytes()
    capsys.readouterr()

    status = cli.main([*command, str(second)])
    captured = capsys.readouterr()
    assert status == 2 and "Traceback" not in captured.err
    assert f"--out {out}: 5 of this import's 5 outputs exist already" in captured.err
    assert "apple/grasp=0/augmentation=0.npz, apple/grasp=0/augmentation=1.npz, " in captured.err
    assert ", ..." in captured.err and "pass --overwrite" in captured.err and "imported" not in captured.out
    assert sample.read_bytes() == before and load_sample(sample).label_modulus_pa == pytest.approx(3.25e6)

    assert cli.main([*command, str(second), "--overwrite"]) == 0
    assert "imported 5 training samples" in capsys.readouterr().out
    assert load_sample(sample).label_modulus_pa is None


@pytest.mark.parametrize("fps", [1e-320, 0.01, 1e6, float("inf"), float("nan"), 0.0])
def test_import_refuses_an_implausible_frame_rate(tmp_path, fps):
    src = tmp_path / "raw"
    make_raw_grasp(src, "apple", 0, n=3)
    with pytest.raises(DatasetError, match=r"fps = .*: expected a frame rate from 0.1 to 10000 Hz"):
        import_dataset(src, layout="raw", out=tmp_path / "out", fps=fps)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.grasp"))


def test_raw_grasp_refuses_frame_times_that_are_not_finite_and_increasing(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=3)
    with pytest.raises(DatasetError, match="not finite and increasing"):
        import_raw_grasp(folder, sensors=load_settings().sensors, labels={}, fps=1e-320)


def test_a_raw_grasp_with_more_frames_than_forces_is_refused(tmp_path):
    # 4 frames per video, 3 forces and 3 widths: the samples cannot be put on the frames' times
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=4)
    write_pickle(folder / "apple_forces.pkl", np.linspace(0.5, 12.0, 3))
    write_pickle(folder / "apple_widths.pkl", np.linspace(0.050, 0.046, 3))
    with pytest.raises(DatasetError, match="4 frames but 3 forces in apple_forces.pkl"):
        import_raw_grasp(folder, sensors=load_settings().sensors)
