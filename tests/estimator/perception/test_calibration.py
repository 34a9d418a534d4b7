"""Calibration fitting, its file, press sets and the checks on every input."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from estimator.errors import CalibrationError, PerceptionError
from estimator.perception import (
    Calibration,
    calibration_fit,
    detect_press_circle,
    fit_calibration,
    load_calibration,
    load_presses,
    split_presses,
    warp_points,
)
from estimator.perception.press_circles import press_rings
from teleop.settings import SensorSettings

PITCH = 0.0295e-3
BALL = 2.0e-3


def small_calibration(**changes):
    lut = np.random.default_rng(3).standard_normal((2, 3, 4, 4, 4, 2)).astype(np.float32)
    fields = {"lut": lut, "image_shape": (20, 30), "pixel_pitch_m": PITCH, "ball_radius_m": BALL,
              "provenance": {"source": "test", "train_indices": [0, 2]}}
    return Calibration(**{**fields, **changes})


# --------------------------------------------------------------------------- the sensor it is for


def test_another_sensors_calibration_is_named_once(caplog, monkeypatch):
    from estimator.measurements import check_calibration_fits
    from teleop.settings import default_settings_path, load_settings

    sensor = load_settings(default_settings_path()).sensor("left")
    assert sensor.model == "wedge" and sensor.serial

    def cal(**made_for):
        return small_calibration(image_shape=sensor.image_shape, pixel_pitch_m=sensor.pixel_pitch_m,
                                 provenance={"sensor": {"finger": "left", "model": "wedge", "serial": sensor.serial,
                                                        **made_for}})

    monkeypatch.setattr("estimator.measurements._WARNED", set())
    with caplog.at_level("WARNING"):
        check_calibration_fits(cal(model="mini"), sensor)
        check_calibration_fits(cal(serial="sim-gelsight-left"), sensor)
        check_calibration_fits(cal(serial="sim-gelsight-left"), sensor)  # said once: a record after another
        check_calibration_fits(cal(finger="right"), sensor)
    assert [r.getMessage().split(": ", 1)[1] for r in caplog.records] == [
        "model 'mini' (this sensor: 'wedge'); its colours may read as other slopes here",
        f"serial 'sim-gelsight-left' (this sensor: {sensor.serial!r}); its colours may read as other slopes here",
        "finger 'right' (this sensor: 'left'); its colours may read as other slopes here",
    ]
    caplog.clear()
    with caplog.at_level("WARNING"):  # the same sensor, or one either side does not name, passes quietly
        check_calibration_fits(cal(), sensor)
        check_calibration_fits(cal(serial=""), sensor)
        check_calibration_fits(cal(), dataclasses.replace(sensor, serial=""))
        check_calibration_fits(small_calibration(image_shape=sensor.image_shape,
                                                 pixel_pitch_m=sensor.pixel_pitch_m), sensor)
    assert not caplog.records


# --------------------------------------------------------------------------- the file


@pytest.mark.slow
def test_round_trip_keeps_every_field_and_the_same_gradients(tmp_path, gelsight_calibration, gelsight_presses):
    path = gelsight_calibration.save(tmp_path / "cal.npz")
    loaded = load_calibration(path)
    np.testing.assert_array_equal(loaded.lut, gelsight_calibration.lut)
    assert gelsight_calibration.smoothing_px == 0.0  # the fit's default
    for name in ("image_shape", "pixel_pitch_m", "ball_radius_m", "relative_range", "smoothing_px", "provenance",
                 "bins", "tiles"):
        assert getattr(loaded, name) == getattr(gelsight_calibration, name), name
    frame = gelsight_presses.images[5]
    for ours, theirs in zip(loaded.gradients(frame, gelsight_presses.reference),
                            gelsight_calibration.gradients(frame, gelsight_presses.reference), strict=True):
        np.testing.assert_array_equal(ours, theirs)
    with np.load(path, allow_pickle=False) as data:  # plain arrays only
        assert json.loads(str(data["meta"]))["format"] == "compliance-teleop.calibration"


def test_table_is_read_only_and_copied():
    lut = np.zeros((1, 1, 4, 4, 4, 2), np.float32)
    calibration = small_calibration(lut=lut)
    lut[...] = 1.0
    assert not calibration.lut.any()
    assert not calibration.lut.flags.writeable


@pytest.mark.parametrize(("member", "match"), [("lut", "missing member"), ("meta", "missing member")])
def test_load_names_a_missing_member(tmp_path, member, match):
    path = small_calibration().save(tmp_path / "cal.npz")
    with np.load(path) as data:
        kept = {k: data[k] for k in data.files if k != member}
    np.savez(tmp_path / "cut.npz", **kept)
    with pytest.raises(CalibrationError, match=f"{match}.*{member}"):
        load_calibration(tmp_path / "cut.npz")


def test_load_refuses_other_files(tmp_path):
    with pytest.raises(CalibrationError, match="does not exist"):
        load_calibration(tmp_path / "none.npz")
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(CalibrationError, match="text.npz"):
        load_calibration(tmp_path / "text.npz")
    np.savez(tmp_path / "pickled.npz", lut=np.array([{"a": 1}], dtype=object))
    with pytest.raises(CalibrationError, match="pickled.npz"):
        load_calibration(tmp_path / "pickled.npz")
    path = small_calibration().save(tmp_path / "cal.npz")
    with np.load(path) as data:
        members = {k: data[k] for k in data.files}
    members["meta"] = np.array(json.dumps({"format": "something else", "version": 1}))
    np.savez(tmp_path / "foreign.npz", **members)
    with pytest.raises(CalibrationError, match="format"):
        load_calibration(tmp_path / "foreign.npz")
    members["lut"] = np.full((1, 1, 4, 4, 4, 2), np.nan, np.float32)
    members["meta"] = np.array(json.dumps({"format": "compliance-teleop.calibration", "version": 1}))
    np.savez(tmp_path / "nan.npz", **members)
    with pytest.raises(CalibrationError, match="nan.npz.*NaN"):
        load_calibration(tmp_path / "nan.npz")


def test_a_file_that_is_no_npz_is_named_as_such_not_by_numpys_pickle_message(tmp_path):
    (tmp_path / "notes.npz").write_text("calibration notes, not arrays")
    np.save(tmp_path / "one.npy", np.zeros(3))
    (tmp_path / "cut.npz").write_bytes(small_calibration().save(tmp_path / "cal.npz").read_bytes()[:60])
    for name in ("notes.npz", "one.npy", "cut.npz"):
        with pytest.raises(CalibrationError, match=f"{name}: not a calibration .npz: expected a zip archive") as caught:
            load_calibration(tmp_path / name)
        assert "allow_pickle" not in str(caught.value)
    np.savez(tmp_path / "pickled.npz", lut=np.array([{"a": 1}], dtype=object))
    with pytest.raises(CalibrationError, match="pickled.npz: not a calibration .npz: a member holds pickled"):
        load_calibration(tmp_path / "pickled.npz")


def test_a_version_1_file_reads_unsmoothed_and_a_version_2_file_needs_its_smoothing(tmp_path):
    path = small_calibration(smoothing_px=1.5).save(tmp_path / "cal.npz")
    with np.load(path) as data:
        members = {k: data[k] for k in data.files if k != "smoothing_px"}
    np.savez(tmp_path / "v2.npz", **members)
    with pytest.raises(CalibrationError, match="v2.npz.*smoothing_px"):
        load_calibration(tmp_path / "v2.npz")
    meta = json.loads(str(members["meta"]))
    members["meta"] = np.array(json.dumps({**meta, "version": 1}))
    np.savez(tmp_path / "v1.npz", **members)
    assert load_calibration(tmp_path / "v1.npz").smoothing_px == 0.0
    members["meta"] = np.array(json.dumps({**meta, "version": 3}))
    np.savez(tmp_path / "v3.npz", **members)
    with pytest.raises(CalibrationError, match="version 3, this software reads 1 and 2"):
        load_calibration(tmp_path / "v3.npz")


def test_smoothing_resolves_a_change_below_the_pixel_noise():
    # A 2 % brighter frame under 3 grey levels of noise per pixel, against a flat reference of 100:
    # bins of 2 % put the mean change in the bin next to the centre, where a pixel alone rarely lands.
    rng = np.random.default_rng(0)
    reference = np.full((60, 80, 3), 100, np.uint8)
    frame = np.clip(np.rint(102 + 3 * rng.standard_normal((60, 80, 3))), 0, 255).astype(np.uint8)
    lut = np.zeros((1, 1, 100, 100, 100, 2), np.float32)
    lut[0, 0, 51, 51, 51, 0] = 1.0  # the centre bin is 50
    share = {}
    for sigma in (0.0, 3.0):
        calibration = small_calibration(lut=lut, image_shape=(60, 80), smoothing_px=sigma)
        gx, _ = calibration.gradients(frame, reference)
        share[sigma] = float((gx[10:-10, 10:-10] == 1.0).mean())
    assert share[0.0] < 0.4 and share[3.0] > 0.95, share


@pytest.mark.parametrize(("changes", "match"), [
    ({"smoothing_px": -1.0}, "smoothing_px"),
    ({"smoothing_px": float("nan")}, "smoothing_px"),
    ({"lut": np.zeros((4, 4, 4, 2), np.float32)}, "lut"),
    ({"lut": np.zeros((1, 1, 4, 4, 4, 2), np.float64)}, "lut"),
    ({"lut": np.zeros((1, 1, 4, 5, 4, 2), np.float32)}, "lut"),
    ({"pixel_pitch_m": 0.0}, "pixel_pitch_m"),
    ({"ball_radius_m": -1.0}, "ball_radius_m"),
    ({"image_shape": (2, 30)}, "image_shape"),
])
def test_impossible_calibrations_cannot_be_built(changes, match):
    with pytest.raises(CalibrationError, match=match):
        small_calibration(**changes)


def test_gradients_are_float32_views_of_the_table():
    calibration = small_calibration()
    frame = np.full((20, 30, 3), 100, np.uint8)
    gx, gy = calibration.gradients(frame, frame)
    assert gx.dtype == gy.dtype == np.float32 and gx.shape == (20, 30)
    # No change falls in the middle bin of each tile: top-left tile, bin (2, 2, 2).
    assert gx[0, 0] == calibration.lut[0, 0, 2, 2, 2, 0]
    assert gy[-1, -1] == calibration.lut[1, 2, 2, 2, 2, 1]
    with pytest.raises(PerceptionError, match="frame"):
        calibration.gradients(frame[:10], frame)


# --------------------------------------------------------------------------- fitting inputs


@pytest.fixture(scope="module")
def few(gelsight_presses):
    return gelsight_presses.reference, gelsight_presses.images[:2], gelsight_presses.centers_px[:2], \
        gelsight_presses.radii_px[:2]


@pytest.mark.parametrize(("change", "match"), [
    (lambda a: {**a, "presses": []}, "presses: empty"),
    (lambda a: {**a, "presses": "images"}, "presses"),
    (lambda a: {**a, "presses": [p.astype(np.float32) for p in a["presses"]]}, r"presses\[0\]"),
    (lambda a: {**a, "presses": [p[:100] for p in a["presses"]]}, r"presses\[0\]"),
    (lambda a: {**a, "reference": a["reference"][..., 0]}, "reference"),
    (lambda a: {**a, "centers_px": a["centers_px"][:1]}, "centers_px"),
    (lambda a: {**a, "radii_px": np.array([60.0, 0.0])}, "radii_px"),
    (lambda a: {**a, "radii_px": np.array([60.0, -3.0])}, "radii_px"),
    (lambda a: {**a, "radii_px": np.array([60.0, 70.0])}, "radii_px.*ball"),
    (lambda a: {**a, "centers_px": np.array([[1.0, np.nan], [3.0, 4.0]])}, "NaN"),
    (lambda a: {**a, "ball_radius_m": 0.0}, "ball_radius_m"),
    (lambda a: {**a, "ball_radius_m": -2e-3}, "ball_radius_m"),
    (lambda a: {**a, "pixel_pitch_m": float("nan")}, "pixel_pitch_m"),
    (lambda a: {**a, "bins": 1}, "bins"),
    (lambda a: {**a, "tiles": (0, 3)}, "tiles"),
    (lambda a: {**a, "refine_passes": -1}, "refine_passes"),
    (lambda a: {**a, "flat_weight": 0.0}, "flat_weight"),
    (lambda a: {**a, "flat_weight": float("inf")}, "flat_weight"),
    (lambda a: {**a, "smoothing_px": -0.5}, "smoothing_px"),
    (lambda a: {**a, "centers_px": np.array([[-500.0, -500.0], [-500.0, -500.0]])}, "no press circle"),
    (lambda a: {**a, "outside_fraction": 0.9}, "outside_fraction = 0.9: expected more than inside_fraction"),
    (lambda a: {**a, "bins": 129}, "bins: expected an integer in"),
    (lambda a: {**a, "tiles": (481, 1)}, "tiles: expected"),  # the GelSight frames are 480 rows
])
def test_bad_inputs_are_refused_by_name(few, change, match):
    reference, presses, centers, radii = few
    args = {"reference": reference, "presses": list(presses), "centers_px": centers, "radii_px": radii,
            "ball_radius_m": BALL, "pixel_pitch_m": PITCH, "refine_passes": 0}
    args = change(args)
    with pytest.raises(CalibrationError, match=match):
        fit_calibration(args.pop("reference"), args.pop("presses"), args.pop("centers_px"),
                        args.pop("radii_px"), **args)


def test_a_press_centred_off_the_image_keeps_its_circle_through_refinement(few):
    reference, presses, centers, radii = few
    centers = np.array(centers, dtype=np.float64)
    centers[1] = (-radii[1] / 2, centers[1][1])  # half its circle still on the image
    calibration = fit_calibration(reference, list(presses), centers, radii, ball_radius_m=BALL,
                                  pixel_pitch_m=PITCH, refine_passes=1)
    assert calibration.provenance["press_centers_px"][1] == pytest.approx(centers[1], abs=0.01)
    assert calibration.provenance["circles_refined"][1] is False


def _fit(few, **options):
    """A quick fit (no refinement, 16 bins) of the two presses, with ``options`` changed."""
    reference, presses, centers, radii = few
    return fit_calibration(reference, list(presses), np.asarray(centers, float), np.asarray(radii, float),
                           ball_radius_m=BALL, pixel_pitch_m=PITCH, **{"refine_passes": 0, "bins": 16, **options})


def test_a_huge_tile_prior_makes_every_tile_the_all_image_table(few):
    lut = _fit(few, tile_prior_count=1e9).lut
    assert np.abs(lut - lut[:1, :1]).max() < 1e-4  # every tile equals the first
    assert np.abs(lut).max() > 0.05  # and the table is not empty


def test_the_flat_ring_and_the_inside_fraction_decide_what_is_labelled(few):
    base = _fit(few, outside_fraction=1.0).lut
    assert not np.array_equal(base, _fit(few, outside_fraction=1.0, flat_fraction=0.5).lut)  # flat ring measured
    assert not np.array_equal(base, _fit(few, outside_fraction=1.0, inside_fraction=0.5).lut)


def test_the_flat_weight_sets_how_far_untouched_gel_reads_flat(few):
    # Flat labels together count flat_weight x the on-ball ones: with a tiny weight the bins that
    # untouched-gel noise lands in are taken over by ball slopes; with the default they read ~0.
    reference, presses, centers, radii = few
    rows, cols = np.indices(reference.shape[:2])
    far = (cols - centers[0][0]) ** 2 + (rows - centers[0][1]) ** 2 > (3 * radii[0]) ** 2

    def untouched_slope(calibration):
        gx, gy = calibration.gradients(presses[0], reference)
        return float(np.hypot(gx, gy)[far].mean())

    default = untouched_slope(_fit(few, bins=48))
    assert default < 2e-3
    assert untouched_slope(_fit(few, bins=48, flat_weight=0.01)) > 5 * default


def test_provenance_keeps_the_remeasured_circles(few):
    reference, presses, _, _ = few
    record = _fit(few, refine_passes=1).provenance
    assert any(record["circles_refined"])
    for i, refined in enumerate(record["circles_refined"]):
        if refined:
            rings = press_rings(presses[i], reference, np.array(record["press_centers_px"][i]),
                                max_radius_px=0.98 * BALL / PITCH, flat_fraction=0.1)
            assert record["press_radii_px"][i] == pytest.approx(rings.contact_px, abs=0.01)
            assert record["press_flat_radii_px"][i] == pytest.approx(rings.flat_px, abs=0.01)


def test_a_sphere_fit_further_than_the_radius_from_the_given_centre_is_discarded(few, monkeypatch):
    _, _, centers, radii = few
    far = SimpleNamespace(center_px=(float(centers[1][0] + 1.5 * radii[1]), float(centers[1][1])))
    near = SimpleNamespace(center_px=(float(centers[0][0] + 2.0), float(centers[0][1])))
    fits = iter([near, far])
    monkeypatch.setattr(calibration_fit, "fit_sphere", lambda depth, **kw: next(fits))
    record = _fit(few, refine_passes=1).provenance
    assert record["circles_refined"] == [True, False]
    assert record["press_centers_px"][1] == pytest.approx(list(centers[1]))


def test_rings_are_measured_inside_the_balls_radius(few, monkeypatch):
    searched = []
    real = calibration_fit.press_rings

    def spy(*args, max_radius_px, **kw):
        searched.append(max_radius_px)
        return real(*args, max_radius_px=max_radius_px, **kw)

    monkeypatch.setattr(calibration_fit, "press_rings", spy)
    _fit(few, refine_passes=1)
    assert searched and max(searched) < BALL / PITCH


@pytest.mark.slow
def test_provenance_records_the_circles_used(gelsight_calibration):
    record = gelsight_calibration.provenance
    assert len(record["press_centers_px"]) == len(record["press_radii_px"]) == 24
    assert sum(record["circles_refined"]) >= 20
    assert record["train_indices"] == list(range(0, 48, 2))
    # Re-measured contact circles sit within a few px of the annotations (both are contact edges).
    radii = np.array(record["press_radii_px"])
    assert np.all((radii > 50) & (radii < 67))


# --------------------------------------------------------------------------- press sets


@pytest.mark.parametrize(("n", "fraction", "expected"), [
    (48, 0.5, list(range(0, 48, 2))),
    (5, 0.5, [0, 2]),
    (3, 1.0, [0, 1, 2]),
    (10, 0.01, [0]),
])
def test_split_is_deterministic_and_spread(n, fraction, expected):
    assert split_presses(n, fraction).tolist() == expected


@pytest.mark.parametrize(("n", "fraction"), [(0, 0.5), (10, 0.0), (10, 1.5)])
def test_split_refuses_bad_requests(n, fraction):
    with pytest.raises(CalibrationError):
        split_presses(n, fraction)


def test_real_pack_loads_as_recorded(gelsight_presses, mini_presses):
    assert len(gelsight_presses) == 48 and len(mini_presses) == 24
    assert gelsight_presses.circles == "recorded" and gelsight_presses.frame == "raw"
    assert gelsight_presses.images.shape == (48, 480, 640, 3)
    assert gelsight_presses.sha256 != mini_presses.sha256


def test_pack_with_missing_members_is_named(tmp_path, gelsight_presses):
    np.savez(tmp_path / "pack.npz", f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2])
    with pytest.raises(CalibrationError, match="touch_center, touch_radius"):
        load_presses(tmp_path / "pack.npz")
    np.savez(tmp_path / "bad.npz", f0=gelsight_presses.reference, imgs=gelsight_presses.images[:2],
             touch_center=np.zeros((3, 2)), touch_radius=np.ones(2))
    with pytest.raises(CalibrationError, match="touch_center"):
        load_presses(tmp_path / "bad.npz")
    with pytest.raises(CalibrationError, match="do not exist"):
        load_presses(tmp_path / "absent.npz")


def test_folder_needs_one_reference_image(tmp_path, gelsight_presses):
    cv2.imwrite(str(tmp_path / "press_1.png"), gelsight_presses.images[0])
    with pytest.raises(CalibrationError, match="f0"):
        load_presses(tmp_path)
    cv2.imwrite(str(tmp_path / "ref.png"), gelsight_presses.reference)
    presses = load_presses(tmp_path)
    assert presses.circles == "none" and len(presses) == 1
    np.testing.assert_array_equal(presses.reference, gelsight_presses.reference)


def test_detected_circles_are_near_the_annotations(gelsight_presses):
    # Detection only seeds the calibration; it must land inside the press.
    for i in range(0, 48, 6):
        (x, y), radius = detect_press_circle(gelsight_presses.images[i], gelsight_presses.reference,
                                             max_radius_px=61.0)
        assert np.hypot(x - gelsight_presses.centers_px[i, 0], y - gelsight_presses.centers_px[i, 1]) < 20
        assert 0.5 * gelsight_presses.radii_px[i] < radius <= 61.0


def test_no_press_is_reported(gelsight_presses):
    with pytest.raises(CalibrationError, match="no press visible"):
        detect_press_circle(gelsight_presses.reference, gelsight_presses.reference)


def test_warping_maps_circles_along(gelsight_presses):
    sensor = SensorSettings()
    subset = gelsight_presses.__class__(
        gelsight_presses.reference, gelsight_presses.images[:2], gelsight_presses.centers_px[:2],
        gelsight_presses.radii_px[:2], "recorded", "raw", None, None, "test", "x",
    )
    warped = subset.in_sensor_frame(sensor)
    assert warped.images.shape == (2, *sensor.image_shape, 3) and warped.warped
    assert warped.frame == "warped_cropped"
    np.testing.assert_allclose(warped.centers_px, warp_points(subset.centers_px, sensor))
    # The default Wedge warp magnifies the raw frame about 1.08x near these points
    # (square root of the Jacobian determinant, checked against finite differences).
    np.testing.assert_allclose(warped.radii_px / subset.radii_px, [1.078, 1.083], atol=0.002)
    # Circles already in the warped frame stay as recorded.
    stated = subset.__class__(**{**subset.__dict__, "frame": "warped_cropped"})
    np.testing.assert_array_equal(stated.in_sensor_frame(sensor).centers_px, subset.centers_px)
    with pytest.raises(CalibrationError, match="raw"):
        warped.__class__(**{**warped.__dict__, "frame": "raw"}).in_sensor_frame(sensor)


def test_a_flat_sensor_keeps_its_raw_presses(mini_presses):
    """A GelSight Mini (model "mini") has no mirror: its raw frame is its image, whatever warp its settings
    keep (here the default Wedge corners), so raw presses and their circles are used as they are."""
    sensor = SensorSettings(model="mini", raw_width_px=640, raw_height_px=480, pixel_pitch_m=2.95e-5)
    subset = mini_presses.__class__(
        mini_presses.reference, mini_presses.images[:2], mini_presses.centers_px[:2],
        mini_presses.radii_px[:2], "recorded", "raw", None, None, "test", "x",
    )
    flat = subset.in_sensor_frame(sensor)
    assert flat.warped and flat.frame == "warped_cropped"
    assert flat.reference is subset.reference and flat.images is subset.images
    assert flat.centers_px is subset.centers_px and flat.radii_px is subset.radii_px
    with pytest.raises(CalibrationError, match="480 x 640"):
        subset.in_sensor_frame(dataclasses.replace(sensor, raw_width_px=320, raw_height_px=240))


def test_press_rings_refuses_a_frame_without_a_press():
    from estimator.perception import press_rings

    flat = np.full((60, 80, 3), 120, np.uint8)
    with pytest.raises(CalibrationError, match="no press visible"):
        press_rings(flat, flat, (40.0, 30.0), max_radius_px=20.0)
    with pytest.raises(CalibrationError, match="center_px"):
        press_rings(flat, flat, (np.nan, 30.0), max_radius_px=20.0)
