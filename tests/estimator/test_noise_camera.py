"""A camera that gives pixel noise, not a gel (estimator.faults.camera_fault): refused like a dead
one, while frames of a gel with the camera's noise (up to the settings' most), a growing contact or
another exposure are measured."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from estimator.faults import camera_fault
from estimator.measure import estimate_grasp
from teleop.catalogue import load_catalogue
from teleop.settings import CONFIG_DIR, load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.sim.simulate import grasp_rng

_spec = importlib.util.spec_from_file_location("_broken_sensors", Path(__file__).with_name("test_broken_sensors.py"))
_broken = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_broken)
build_record, calibration, with_streams, SETTINGS = (_broken.build_record, _broken.calibration,
                                                     _broken.with_streams, _broken.SETTINGS)


def gel_frames(rng, *, noise_levels=2.0, n=4, shape=(48, 64)):
    """A shaded gel's no-contact frame and ``n`` frames of a contact growing to a third of the pad,
    each with the camera's noise (``noise_levels``, 8-bit levels)."""
    rows, cols = np.indices(shape)
    gel = np.stack([60 + rows, 90 + cols, 120 + 0.5 * (rows + cols)], axis=-1).astype(float)
    r2 = (rows - shape[0] / 2) ** 2 + (cols - shape[1] / 2) ** 2

    def shot(image):
        return np.clip(image + rng.normal(0, noise_levels, image.shape), 0, 255).astype(np.uint8)

    frames = []
    for k in range(1, n + 1):
        contact = r2 < (k / n * shape[0] / 3) ** 2
        frames.append(shot(gel + 60 * contact[..., None]))
    return shot(gel), frames


def test_pixel_noise_is_refused_and_a_noisy_gel_pressed_over_half_its_pad_is_not():
    rng = np.random.default_rng(0)
    t = np.arange(4) * 0.04
    reference, frames = gel_frames(rng)
    assert camera_fault(reference, frames, t, "left") == ""
    # A press that covers most of the pad in its last frames: the first is still mostly still gel.
    wide = [np.where(np.arange(64)[None, :, None] < 8 + 16 * k, f // 2, f).astype(np.uint8) for k, f in enumerate(frames)]
    assert camera_fault(reference, wide, t, "left") == ""
    noise = [rng.integers(0, 256, reference.shape, dtype=np.uint8) for _ in range(5)]
    why = camera_fault(np.median(noise[:3], axis=0).astype(np.uint8), noise[3:] * 2, t, "left")
    assert "camera of finger 'left'" in why and "pixel noise" in why
    # A gel seen through pixel noise in its loading frames only: the reference is still a gel.
    assert "pixel noise" in camera_fault(reference, noise[:4], t, "left")


def test_an_exposure_shift_or_gain_is_not_pixel_noise():
    rng = np.random.default_rng(2)
    t = np.arange(4) * 0.04
    reference, frames = gel_frames(rng)
    for exposed in (lambda f: f.astype(int) + 12, lambda f: f.astype(int) - 12, lambda f: 1.3 * f):
        assert camera_fault(reference, [np.clip(exposed(f), 0, 255).astype(np.uint8) for f in frames], t, "left") == ""


@pytest.mark.slow
def test_a_record_of_pixel_noise_frames_refuses_the_tactile_methods(calibration):
    record = build_record(3e5)
    rng = np.random.default_rng(1)
    noisy = with_streams(record, images=lambda i, image: rng.integers(0, 256, image.shape, dtype=np.uint8))
    for method in ("series", "hertz"):
        est = estimate_grasp(noisy, method, settings=SETTINGS, calibration=calibration)
        assert not est and "pixel noise" in est.reason and "camera of finger 'left'" in est.reason
    assert estimate_grasp(with_streams(record, images=lambda i, image: image), "series", settings=SETTINGS,
                          calibration=calibration)


def test_a_simulated_grasp_at_the_most_camera_noise_the_settings_allow_is_measured():
    # camera_noise 50, the settings' most: over half the pixel values move by over 10 levels, once refused as noise.
    settings = load_settings()
    noisy = dataclasses.replace(settings, simulation=dataclasses.replace(settings.simulation, camera_noise=50.0))
    puck = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "silicone_puck_shore10a")
    record, _ = simulate_grasp(puck, settings=noisy, rng=grasp_rng(0, puck, 0), seed=0)
    est = estimate_grasp(record, "series", settings=settings,
                         calibration=CONFIG_DIR / "calibration" / "sim-wedge-left.npz")
    assert est.state == "ok", est.reason
