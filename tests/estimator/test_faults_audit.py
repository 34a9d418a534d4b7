"""The sensor-fault checks (estimator.faults) on their own inputs: which times are not seconds, which
widths cannot be a gripper's, which frames cannot show a gel, and what a refusal keeps of the phase."""

from __future__ import annotations

import numpy as np
import pytest

from estimator import faults
from estimator.faults import camera_fault, checked_frames, checked_phase, period_fault
from estimator.load_phase import find_load_phase
from estimator.segment import Segment

T = np.array([1.0, 1.1, 1.2])


def grasp(*, force_start_s=0.0, width_start_s=0.0, closes_m=0.0, width0_m=0.05, force_hz=100.0, width_hz=50.0):
    """Force rising 0 to 15 N over 1-2.5 s and widths closing ``closes_m`` meanwhile, at the given rates and
    start times: the arrays ``checked_phase`` takes, and the phase found on them."""
    t = np.arange(force_start_s, 3.5, 1 / force_hz)
    tw = np.arange(width_start_s, 3.5, 1 / width_hz)
    force = np.interp(t, [0, 1, 2.5, 3.5], [0, 0, 15, 15])
    width = width0_m - np.interp(tw, [0, 1, 2.5, 3.5], [0, 0, closes_m, closes_m])
    return t, tw, find_load_phase(t, force, tw, width, contact_force_n=0.75)


def checked(t, tw, phase, *, force_hz=100.0, width_hz=50.0):
    return checked_phase(phase, force_t_s=t, width_t_s=tw, force_hz=force_hz, width_hz=width_hz)


def test_repeated_or_unknown_sample_times_are_not_read_as_another_rate():
    t = np.arange(200) / 100.0
    assert period_fault(np.repeat(t, 3), 100.0, "force samples") == ""  # each time delivered three times
    assert period_fault(np.append(t, [np.nan, np.inf]), 100.0, "force samples") == ""


def test_widths_that_read_zero_at_the_onset_are_refused_as_such_not_as_still():
    t, tw, phase = grasp(width0_m=0.0)
    refused = checked(t, tw, phase)
    assert not refused and "gripper width 0 m at the contact onset" in refused.reason
    assert refused.flags.count("implausible_width") == 1


@pytest.mark.parametrize(("force_start_s", "width_start_s"), [(1.5, 0.0), (0.0, 1.5)])
def test_still_widths_are_judged_only_when_both_streams_start_before_the_onset(force_start_s, width_start_s):
    t, tw, phase = grasp(force_start_s=force_start_s, width_start_s=width_start_s)
    assert phase and checked(t, tw, phase), "one stream starts in contact: the approach is not on record"
    t, tw, phase = grasp()
    assert not checked(t, tw, phase)


def test_a_width_refusal_flags_the_width_once_and_keeps_the_phases_notes_and_baseline():
    t, tw, phase = grasp()
    phase = type(phase)(**{**phase.__dict__, "flags": ("implausible_width",), "force_baseline_n": 0.25,
                           "notes": ("a note",)})
    refused = checked(t, tw, phase)
    assert not refused and "stay within" in refused.reason
    assert refused.flags == ("implausible_width",) and refused.notes == ("a note",)
    assert refused.force_baseline_n == 0.25


def test_a_rate_refusal_names_the_stream_without_flagging_the_width():
    t, tw, phase = grasp(closes_m=1e-3)
    assert checked(t, tw, phase)
    refused = checked(t, tw * 1e3, phase)  # widths in milliseconds
    assert not refused and refused.reason.startswith("width samples come every") and refused.flags == phase.flags
    unfound = find_load_phase(t, np.zeros_like(t), tw, np.full_like(tw, 0.05), contact_force_n=0.75)
    refused = checked(t * 1e3, tw, unfound)  # no contact, and the force's times not seconds
    assert not unfound and refused.reason.startswith("force samples come every")


def test_widths_are_judged_at_their_own_rate_not_the_forces():
    t, tw, phase = grasp(closes_m=1e-3, force_hz=1000.0, width_hz=5.0)
    assert checked(t, tw, phase, force_hz=1000.0, width_hz=5.0)


def test_the_frame_rate_of_a_grasp_without_a_loading_phase_is_not_judged():
    unfound = Segment(reason="no contact")
    assert checked_frames(unfound, T * 1e9, camera_hz=30.0, finger="left") is unfound
    found = Segment(reason="", frame_reason="")
    assert "not in seconds" in checked_frames(found, np.arange(10) * 1e9 / 30, camera_hz=30.0, finger="left").frame_reason


def shaded(shape=(48, 64)) -> np.ndarray:
    rows, cols = np.indices(shape)
    return np.stack([60 + rows, 90 + cols, 120 + 0.5 * (rows + cols)], axis=-1).astype(np.uint8)


def test_a_dead_reference_is_named_though_the_loading_frames_show_a_gel():
    gel = shaded()
    why = camera_fault(np.zeros_like(gel), [gel, gel + 1], T[:2], "left")
    assert "the no-contact reference of the camera of finger 'left' has no texture: black" in why


def test_the_texture_bound_and_the_words_for_a_flat_frame():
    half = np.full((8, 8, 3), 100, np.uint8)
    half[:4] = 104  # spread exactly TEXTURE_LEVELS: texture
    assert "no texture" not in camera_fault(half, [half + 1], T[:1], "left")
    for level, seen in ((15, "black"), (16, "one flat grey"), (239, "one flat grey"), (240, "saturated")):
        flat = np.full((8, 8, 3), level, np.uint8)
        assert f"has no texture: {seen} (mean level {level}" in camera_fault(flat, [], T[:0], "left")


def test_one_loading_frame_equal_to_the_reference_is_not_a_frozen_camera():
    gel = shaded()
    assert camera_fault(gel, [gel, gel + 2, gel + 4], T, "left") == ""
    assert "bit-identical" in camera_fault(gel, [gel, gel], T[:2], "left")


def test_no_loading_frame_is_no_fault_of_the_camera():
    assert camera_fault(shaded(), [], T[:0], "left") == ""


def test_frames_under_one_cell_are_not_correlated():
    rng = np.random.default_rng(1)
    tiny = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
    assert camera_fault(tiny, [rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)], T[:1], "left") == ""


def test_a_gel_image_inverted_or_without_cell_structure_is_not_the_gel():
    gel = shaded()
    inverted = camera_fault(gel, [255 - gel], T[:1], "left")
    assert "lost the spatial structure" in inverted and "correlation -1.00 at most" in inverted
    board = ((np.indices(gel.shape[:2]).sum(axis=0) % 2) * 100 + 60).astype(np.uint8)
    checkered = np.repeat(board[:, :, None], 3, axis=2)  # texture on every pixel, every cell the same mean
    assert "correlation 0.00 at most" in camera_fault(gel, [checkered], T[:1], "left")


def test_the_refusal_says_the_best_correlation_of_the_loading_frames():
    gel = shaded().astype(float)
    rng = np.random.default_rng(2)
    noise = rng.uniform(0, 255, gel.shape)
    frames = [(0.02 * gel + 0.98 * noise).astype(np.uint8), rng.integers(0, 256, gel.shape, dtype=np.uint8)]
    structure = faults._cell_means(gel.astype(np.uint8))
    best = max(faults._correlation(faults._cell_means(f), structure) for f in frames)
    assert best < faults.STRUCTURE_CORRELATION
    assert f"correlation {best:.2f} at most" in camera_fault(gel.astype(np.uint8), frames, T[:2], "left")


def gel_seen_through(noise_sd: float, *, shading: float = 1.0, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A gel's reference (its shading scaled by ``shading``) and a loading frame of it with pixel noise of
    ``noise_sd`` levels."""
    gel = 128 + shading * (shaded().astype(float) - 110)
    noisy = gel + np.random.default_rng(seed).normal(0, noise_sd, gel.shape)
    return np.clip(gel, 0, 255).astype(np.uint8), np.clip(noisy, 0, 255).astype(np.uint8)


def test_a_gel_under_heavy_pixel_noise_keeps_its_structure_over_whole_cells():
    reference, frame = gel_seen_through(40.0, shading=0.3)  # a pixel's noise is ten times the cells' spread
    assert camera_fault(reference, [frame], T[:1], "left") == ""


def test_a_loading_frame_half_like_its_reference_is_a_gel():
    # A stiff object squeezed hard correlates by about 0.5 (module notes): well above the bound.
    reference, frame = gel_seen_through(60.0, shading=0.3)
    structure = faults._cell_means(reference)
    assert 0.4 < faults._correlation(faults._cell_means(frame), structure) < 0.65
    assert camera_fault(reference, [frame], T[:1], "left") == ""


def test_a_faint_reference_is_still_judged_and_pixel_noise_refused_against_it():
    reference, _ = gel_seen_through(0.0, shading=0.1)
    assert 0.5 < float(faults._cell_means(reference).std()) < 3.0
    noise = np.random.default_rng(4).integers(0, 256, reference.shape, dtype=np.uint8)
    assert "lost the spatial structure" in camera_fault(reference, [noise], T[:1], "left")


def test_a_nearly_flat_frame_has_no_texture():
    flat = (128 + np.random.default_rng(5).normal(0, 1.0, (48, 64, 3))).astype(np.uint8)
    assert "has no texture: one flat grey" in camera_fault(flat, [], T[:0], "left")
