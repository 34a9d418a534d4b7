"""Published-dataset import: the edges the other import tests leave open (estimates of zero, per-frame
members, the gripper's default width, frame rates, write failures, the skip callback)."""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from support.pickles import write_pickle

from estimator.errors import SampleError
from estimator.training.samples import load_sample
from teleop.errors import DatasetError
from teleop.record import read_record
from teleop.settings import load_settings
from teleop.system import dataset_preprocessed
from teleop.system.dataset import SkippedItem, import_dataset
from teleop.system.dataset_preprocessed import import_preprocessed_sample
from teleop.system.dataset_raw import import_raw_grasp, raw_sensors, read_mjpg_packets

RAW_SHAPE = (480, 640, 3)
IMAGE_SHAPE = (250, 350)


def write_mjpg(path: Path, n: int, *, markers: bool) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (RAW_SHAPE[1], RAW_SHAPE[0]))
    assert writer.isOpened()
    for k in range(n):
        frame = np.full(RAW_SHAPE, 40 + 30 * k, np.uint8)
        if markers:
            frame[::40, ::40] = 0
        writer.write(frame)
    writer.release()


def make_raw_grasp(root: Path, name: str, index: int, n: int = 3) -> Path:
    folder = root / name / f"grasp={index}"
    folder.mkdir(parents=True)
    write_mjpg(folder / f"{name}.avi", n, markers=False)
    write_mjpg(folder / f"{name}_markers.avi", n, markers=True)
    write_pickle(folder / f"{name}_forces.pkl", np.linspace(0.5, 12.0, n))
    write_pickle(folder / f"{name}_widths.pkl", np.linspace(0.050, 0.046, n))
    return folder


def make_preprocessed(root: Path, name: str = "apple", grasp: int = 0, aug: int = 0, n: int = 3, **members) -> Path:
    folder = root / name / f"grasp={grasp}" / f"augmentation={aug}"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(grasp * 10 + aug)
    values = {
        "RGB.pkl": rng.normal(0, 20, (n, *IMAGE_SHAPE, 3)),
        "depth.pkl": rng.uniform(0, 1.5, (n, *IMAGE_SHAPE)),
        "RGB_markers.pkl": rng.normal(0, 20, (n, *IMAGE_SHAPE, 3)),
        "depth_markers.pkl": rng.uniform(0, 1.5, (n, *IMAGE_SHAPE)),
        "forces.pkl": np.linspace(2.0, 11.0, n),
        "widths.pkl": np.linspace(0.031, 0.0295, n),
        "elastic_estimate.pkl": 2.0e6,
        "hertz_estimate.pkl": 1.5e5,
    }
    values.update({member.replace("_pkl", ".pkl"): value for member, value in members.items()})
    for member, value in values.items():
        write_pickle(folder / member, value)
    return folder


# --------------------------------------------------------------------------- preprocessed


@pytest.mark.parametrize("estimate", [0.0, 0, -0.0])
def test_a_published_estimate_of_zero_is_not_available(tmp_path, estimate):
    sample = import_preprocessed_sample(make_preprocessed(tmp_path, elastic_estimate_pkl=estimate))
    assert sample.elastic_estimate_pa is None and sample.hertz_estar_pa == 1.5e5


@pytest.mark.parametrize("estimate", [np.array([2e6]), np.array([[7]], dtype=np.int32), np.float32(3.5e5)])
def test_a_published_estimate_of_one_number_in_any_shape_is_read(tmp_path, estimate):
    sample = import_preprocessed_sample(make_preprocessed(tmp_path, hertz_estimate_pkl=estimate))
    assert sample.hertz_estar_pa == pytest.approx(float(np.asarray(estimate).reshape(())))


@pytest.mark.parametrize("estimate", [True, np.array([True]), "2e6", np.array([], dtype=float)])
def test_a_published_estimate_that_is_not_one_number_is_refused(tmp_path, estimate):
    folder = make_preprocessed(tmp_path, elastic_estimate_pkl=estimate)
    with pytest.raises(DatasetError, match=r"elastic_estimate\.pkl: expected one number \(Pa\)"):
        import_preprocessed_sample(folder)


@pytest.mark.parametrize("member", ["depth.pkl", "RGB_markers.pkl", "depth_markers.pkl", "widths.pkl"])
def test_every_per_frame_member_must_have_the_frames_of_rgb(tmp_path, member):
    other = make_preprocessed(tmp_path / "four", n=4)
    folder = make_preprocessed(tmp_path / "three", n=3)
    (folder / member).write_bytes((other / member).read_bytes())
    with pytest.raises(DatasetError, match=rf"{member}: expected shape \(3,"):
        import_preprocessed_sample(folder)


def test_the_marker_images_and_depths_are_the_marker_members(tmp_path):
    folder = make_preprocessed(tmp_path)
    sample = import_preprocessed_sample(folder)
    markers = pickle.loads((folder / "RGB_markers.pkl").read_bytes())
    np.testing.assert_array_equal(sample.rgb_diff_markers, markers.astype(np.float32))
    depth = pickle.loads((folder / "depth_markers.pkl").read_bytes())
    np.testing.assert_allclose(sample.depth_markers_m, depth * 1e-3, rtol=1e-6)


@pytest.mark.parametrize(("member", "value"), [
    ("RGB_markers.pkl", np.full((3, *IMAGE_SHAPE, 3), -1100.0)),
    ("RGB.pkl", np.full((3, *IMAGE_SHAPE, 3), 1024.5)),
    ("depth.pkl", np.full((3, *IMAGE_SHAPE), -150.0)),
    ("depth_markers.pkl", np.full((3, *IMAGE_SHAPE), 500.0)),
])
def test_images_and_depths_beyond_their_limit_either_side_are_refused(tmp_path, member, value):
    folder = make_preprocessed(tmp_path, **{member.replace(".pkl", "_pkl"): value})
    with pytest.raises(DatasetError, match=rf"{member}: expected .* within \+-"):
        import_preprocessed_sample(folder)


def test_images_and_depths_at_their_limits_are_kept(tmp_path):
    folder = make_preprocessed(tmp_path, RGB_pkl=np.full((3, *IMAGE_SHAPE, 3), -1024.0),
                               depth_pkl=np.full((3, *IMAGE_SHAPE), 100.0))
    sample = import_preprocessed_sample(folder)
    assert sample.rgb_diff.min() == -1024.0 and sample.depth_m.max() == pytest.approx(0.1)


def test_without_a_width_bound_the_default_gripper_bounds_the_widths(tmp_path):
    folder = make_preprocessed(tmp_path, widths_pkl=np.array([0.3, 0.2, 0.1]))
    with pytest.raises(DatasetError, match=r"widths must lie within 0 to 0\.085 m"):
        import_preprocessed_sample(folder)


def test_a_range_error_stays_a_dataset_error_not_a_sample_error(tmp_path):
    folder = make_preprocessed(tmp_path, depth_pkl=np.full((3, *IMAGE_SHAPE), 500.0))
    with pytest.raises(DatasetError) as info:
        import_preprocessed_sample(folder)
    assert not isinstance(info.value, SampleError)


def test_a_sample_error_is_skipped_naming_the_folder(tmp_path, monkeypatch):
    src = tmp_path / "pre"
    folder = make_preprocessed(src)

    def refuse(**fields):
        raise SampleError("the arrays do not form a sample")

    monkeypatch.setattr(dataset_preprocessed, "TrainingSample", refuse)
    seen: list[SkippedItem] = []
    summary = import_dataset(src, layout="preprocessed", out=tmp_path / "out", on_skip=seen.append)
    assert not summary.imported and seen == summary.skipped
    assert summary.skipped[0].reason == f"{folder}: the arrays do not form a sample"


# --------------------------------------------------------------------------- raw


def test_a_raw_grasp_with_more_forces_than_frames_is_refused(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=3)
    write_pickle(folder / "apple_forces.pkl", np.linspace(0.5, 12.0, 4))
    write_pickle(folder / "apple_widths.pkl", np.linspace(0.05, 0.046, 4))
    with pytest.raises(DatasetError, match="3 frames but 4 forces"):
        import_raw_grasp(folder, sensors=load_settings().sensors)


def test_a_raw_grasp_at_an_infinite_frame_rate_is_refused(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=3)
    with pytest.raises(DatasetError, match="not finite and increasing"):
        import_raw_grasp(folder, sensors=load_settings().sensors, fps=float("inf"))


def test_raw_forces_below_the_noise_tolerance_are_refused(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=3)
    write_pickle(folder / "apple_forces.pkl", np.array([1.0, -2.0, 3.0]))
    with pytest.raises(DatasetError, match=r"apple_forces\.pkl: forces must be >= 0 N"):
        import_raw_grasp(folder, sensors=load_settings().sensors)


def test_raw_widths_are_bounded_by_the_width_given(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=3)  # widths up to 0.05 m
    with pytest.raises(DatasetError, match=r"apple_widths\.pkl: widths must lie within 0 to 0\.045 m"):
        import_raw_grasp(folder, sensors=load_settings().sensors, max_width_m=0.04)


def test_a_video_of_another_size_than_the_sensor_is_refused(tmp_path):
    folder = make_raw_grasp(tmp_path / "raw", "apple", 0, n=2)
    writer = cv2.VideoWriter(str(folder / "apple.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (320, 240))
    for _ in range(2):
        writer.write(np.zeros((240, 320, 3), np.uint8))
    writer.release()
    with pytest.raises(DatasetError, match=r"apple\.avi: frames are \(240, 320, 3\), sensor 'left' expects"):
        import_raw_grasp(folder, sensors=load_settings().sensors)


def test_a_video_not_in_mjpg_is_refused(tmp_path):
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"XVID"), 30.0, (64, 48))
    if not writer.isOpened():
        pytest.skip("this OpenCV build writes no XVID")
    for _ in range(2):
        writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    with pytest.raises(DatasetError, match="expected an MJPG video"):
        read_mjpg_packets(path)


def test_a_video_missing_its_last_frame_is_refused_as_truncated(tmp_path):
    path = tmp_path / "v.avi"
    write_mjpg(path, 4, markers=False)
    data = path.read_bytes()
    last = data.rfind(b"\xff\xd8\xff")
    path.write_bytes(data[:last])  # the header still lists 4 frames
    try:
        packets, _ = read_mjpg_packets(path)
    except DatasetError as exc:
        assert "truncated video: its header lists 4 frames, 3 read" in str(exc)
    else:
        pytest.fail(f"a video cut before its last frame was read whole ({len(packets)} frames)")


def test_the_plain_and_marker_sensors_are_told_apart_whatever_their_order():
    sensors = load_settings().sensors
    plain, marked = raw_sensors(tuple(reversed(sensors)))
    assert not plain.markers and marked.markers
    with pytest.raises(DatasetError, match="one sensor without markers and one with"):
        raw_sensors([s for s in sensors if s.markers])


def test_a_raw_grasp_is_imported_at_the_frame_rate_given(tmp_path):
    src = tmp_path / "raw"
    make_raw_grasp(src, "apple", 4, n=3)
    summary = import_dataset(src, layout="raw", out=tmp_path / "out", fps=15.0)
    record = read_record(Path(summary.imported[0]))
    np.testing.assert_array_equal(record.stream("right").t_s, np.arange(3) / 15.0)
    assert record.provenance.extra == {"source_dir": str(src / "apple" / "grasp=4"), "grasp": 4, "fps": 15.0}


# --------------------------------------------------------------------------- the whole import


def test_the_lowest_frame_rate_is_admitted(tmp_path):
    make_preprocessed(tmp_path / "pre")
    assert import_dataset(tmp_path / "pre", layout="preprocessed", out=tmp_path / "out", fps=0.1).imported


def test_a_single_output_already_there_is_refused(tmp_path):
    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src)
    import_dataset(src, layout="preprocessed", out=out)
    with pytest.raises(DatasetError, match="1 of this import's 1 outputs exist already"):
        import_dataset(src, layout="preprocessed", out=out)


def test_an_output_that_cannot_be_written_stops_the_import_naming_it(tmp_path):
    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src, "apple")
    out.mkdir()
    (out / "apple").write_text("a file where the object's folder goes")
    with pytest.raises(DatasetError, match=rf"cannot write {out / 'apple' / 'grasp=0' / 'augmentation=0.npz'}"):
        import_dataset(src, layout="preprocessed", out=out)


def test_the_summary_counts_what_was_labelled_imported_and_skipped(tmp_path, object_table):
    src, out = tmp_path / "pre", tmp_path / "out"
    make_preprocessed(src, "apple", 0, 0, hertz_estimate_pkl=np.nan)
    make_preprocessed(src, "mystery", 0, 0)
    broken = make_preprocessed(src, "zz_broken", 0, 0)
    (broken / "RGB.pkl").unlink()
    summary = import_dataset(src, layout="preprocessed", out=out, objects=object_table)
    assert summary.to_json() == {
        "layout": "preprocessed", "source": str(src), "out": str(out), "imported": 2, "skipped": 1,
        "labelled": 1, "unavailable_estimates": 1,
        "skipped_items": [{"path": str(broken), "reason": summary.skipped[0].reason}],
    }
    assert load_sample(out / "mystery" / "grasp=0" / "augmentation=0.npz").label_modulus_pa is None


@pytest.mark.parametrize(("member", "value", "says"), [
    ("forces.pkl", [np.zeros(3), np.zeros(4)], r"forces\.pkl: expected an array, got a list that makes none"),
    ("elastic_estimate.pkl", [1.0, [2.0, 3.0]], r"elastic_estimate\.pkl: expected an array, got a list that makes none"),
])
def test_a_ragged_list_is_skipped_and_the_import_carries_on(tmp_path, member, value, says):
    # np.asarray of a ragged list raises a plain ValueError: one such file must not stop the import.
    src = tmp_path / "pre"
    make_preprocessed(src, "apple", 0, 0)
    bad = make_preprocessed(src, "apple", 0, 1, **{member.replace(".pkl", "_pkl"): value})
    summary = import_dataset(src, layout="preprocessed", out=tmp_path / "out")
    assert [Path(p).name for p in summary.imported] == ["augmentation=0.npz"]
    [skipped] = summary.skipped
    assert skipped.path == str(bad) and re.search(says, skipped.reason), skipped.reason
    assert str(bad / member) in skipped.reason
