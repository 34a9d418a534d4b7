"""A broad, shallow press read back at its true depth: a 20 mm radius sphere at 10 N.

Acceptance criterion: a 20 mm radius sphere of the gel's own modulus pressed at 10 N
reconstructs to within 20 % of its simulated peak indentation on every optics model
(``wedge``, ``gelsight``, ``gelsight_mini``). The simulator solves the press (the layered
BEM contact of :func:`teleop.sim.grasp.load_curve`, the sphere centred on the left pad),
renders it through the rig's optics and camera (noise, JPEG), and the estimator's own
perception reconstructs it: the frame and its no-contact reference on the estimator's depth
grid (``estimator.depth_binning``), the rig's shipped calibration, the Poisson solve, and the
peak-depth feature. The reference is the true gel surface depth at the peak of the press
(the solver's gel displacement), never used by the reconstruction.

Why: the calibrations are fitted on steep 2 mm ball presses, and broad shallow contacts
(slopes of a few hundredths over most of the contact) used to be read 5-15x too small.

The reconstructed peak is the estimator's peak-depth feature (the peak of the lightly smoothed
depth map), and it must lie on the press (where the gel is sunk at least half the simulated
peak), so that an artefact elsewhere on the pad cannot pass for it.

Status (seed 0, binning 2, the shipped calibrations; ratio = reconstructed / simulated peak):
the criterion holds on the ``wedge`` optics (0.255 mm simulated, 0.82); the two table optics are
expected to fail (strict xfail, with the reason): ``gelsight`` 0.264 mm, 0.35; ``gelsight_mini`` 0.478 mm, 0.18. Causes:

1. Small slopes read small (all optics): a slope below ~0.05 (Wedge) changes the colour by less
   than the table's centre bin and reads as flat. The GelSight tables' optics are less sensitive:
   on this press, slopes of 0.1-0.3 change the colour by about one bin width (4 %), and the
   pixels' gradients (median, along the true slope) read at about 1 % of theirs, against 97 % on
   the Wedge. A lookup interpolated between bins reads no more: the bins next to the centre hold
   small slopes themselves. The flat-gel weight of the calibration fit
   (:mod:`estimator.perception.calibration_fit`, where the weights tried and their cost in noise
   are listed) keeps the flat majority of the calibration pixels from pulling those bins to zero,
   but does not lift them to the slopes the press has. Smoothing the colours before the lookup
   (:mod:`estimator.perception.calibration_fit`, "Smoothing") reads 1.06, 0.52 and 0.29 of the
   peak on the three optics; the shipped calibrations have none, as their models were trained
   without it. A table filled by inverting the mean colour of each slope reads 1.07, 0.57 and
   0.24, but fails on real presses (module notes there, "Flat-gel weight").
2. The contact is wider than the GelSight pads (both table optics): their pad is 17.7 x 13.0 mm
   and the contact radius about 8 mm, so the gel is sunk at the pad's edges, where the Poisson
   solve anchors the depth at zero: even the exact gradients integrate to only 0.77 (R1.5) and
   0.36 (Mini) of the peak (the Wedge's, 1.07). No table can bring these two within 20 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage

from estimator.features import contact_features
from estimator.measurements import calibration_path
from estimator.perception import load_calibration, reconstruct_depth
from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration
from estimator.settings import estimator_settings
from teleop.catalogue import ObjectSpec
from teleop.settings import CONFIG_DIR, default_settings_path, load_settings
from teleop.sim.grasp import _to_image, contact_grid, load_curve
from teleop.sim.optics import OpticsRenderer
from teleop.sim.shapes import Pose, make_scene

BALL_RADIUS_M = 20e-3
FORCE_N = 10.0
TOLERANCE = 0.2

SETTINGS = {
    "wedge": default_settings_path(),
    "gelsight": CONFIG_DIR / "rigs" / "gelsight.toml",
    "gelsight_mini": CONFIG_DIR / "rigs" / "gelsight_mini.toml",
}
# Optics on which the criterion does not hold yet, with the measured ratio and the cause
# (module notes): they run and are expected to fail (strict: one that starts to pass fails the
# run, so its entry is removed then).
NOT_MET = {
    "gelsight": "reads 0.35 of the peak, off the press centre: the contact is wider than the "
                "13 mm pad, whose sunk edges the depth is anchored to (exact gradients give 0.77), "
                "and the table reads slopes of 0.1-0.3 at about 1 % of their value",
    "gelsight_mini": "reads 0.18 of the peak, off the press: the contact sinks almost the whole "
                     "pad border, where the depth is anchored (exact gradients give 0.36), and the "
                     "table reads slopes of 0.1-0.3 at about 1 % of their value",
}


def _optics_params(optics_names):
    return [pytest.param(name, marks=pytest.mark.xfail(strict=True, reason=f"criterion not met: {NOT_MET[name]}"))
            if name in NOT_MET else name for name in optics_names]


def sphere_press(optics: str, *, seed: int = 0):
    """Simulate the press on the left pad and reconstruct it.

    Returns the settings, the load curve, the true gel depth (m) on the image grid at 10 N,
    the reconstructed depth (m) on the estimator's depth grid, and its peak-depth feature (m).
    """
    settings = load_settings(SETTINGS[optics])
    sensors = {s.finger: s for s in settings.sensors}
    sensor = sensors["left"]
    assert sensor.optics == optics
    grid_px = settings.simulation.grid_px
    ball = ObjectSpec(name="20 mm sphere", shape="sphere", material="rubber",
                      modulus_pa=sensor.gel_modulus_pa, poisson=settings.sensing.object_poisson,
                      size_m=(2 * BALL_RADIUS_M,) * 3, texture_m=1e-9)
    shape, cell = contact_grid(sensor, grid_px)
    scene = make_scene(ball, Pose(rotation=np.eye(3), offset_m=(0.0, 0.0)), shape=shape, cell_m=cell,
                       fingers=tuple(sensors), rng=np.random.default_rng(seed))
    curve = load_curve(ball, scene, sensors=sensors, grid_px=grid_px, max_force_n=FORCE_N,
                       finger_stiffness_n_per_m=settings.gripper.finger_stiffness_n_per_m)
    truth = _to_image(curve.gel_map("left", FORCE_N), sensor, grid_px).astype(np.float64)

    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(seed))
    reference_jpeg = camera.capture(np.zeros(sensor.image_shape))
    frame_jpeg = camera.capture(truth)
    binning = estimator_settings(settings).depth_binning
    grid = depth_grid(sensor, binning)
    calibration = grid_calibration(load_calibration(calibration_path(sensor)), binning)
    depth = reconstruct_depth(frame_on_grid(frame_jpeg, "jpeg", sensor, binning=binning),
                              frame_on_grid(reference_jpeg, "jpeg", sensor, binning=binning), calibration)
    features = contact_features(depth[None], pixel_pitch_m=grid.pixel_pitch_m,
                                contact_threshold_m=grid.contact_threshold_m)
    return settings, curve, truth, depth, float(features.peak_depth_m[0])


@pytest.mark.parametrize("optics", list(SETTINGS))
def test_press_is_a_broad_shallow_contact_of_10_n(optics):
    settings, curve, truth, depth, _ = sphere_press(optics)
    assert curve.model == "bem-layer"  # the gel layer matters: Hertz would be wrong here
    assert curve.force_n[-1] == pytest.approx(FORCE_N)
    contact = curve.fingers["left"].solutions[-1]
    assert contact.converged and contact.force_n == pytest.approx(FORCE_N, rel=1e-6)
    # Broad and shallow: a contact over 5 mm in radius, a few tenths of a mm deep.
    cell_m = contact_grid(settings.sensor("left"), settings.simulation.grid_px)[1]
    assert math.sqrt(contact.contact.sum() * cell_m[0] * cell_m[1] / math.pi) > 5e-3
    assert 0.1e-3 < truth.max() < 1e-3
    binning = estimator_settings(settings).depth_binning
    assert depth.shape == tuple(side // binning for side in truth.shape)
    assert np.isfinite(depth).all()


@pytest.mark.parametrize("optics", _optics_params(SETTINGS))
def test_sphere_of_gel_modulus_reconstructs_to_its_peak_indentation(optics):
    settings, _, truth, depth, peak = sphere_press(optics)
    simulated = float(truth.max())
    ratio = peak / simulated
    assert abs(ratio - 1.0) <= TOLERANCE, (
        f"{optics}: reconstructed peak {peak * 1e3:.3f} mm, simulated {simulated * 1e3:.3f} mm "
        f"(ratio {ratio:.3f})"
    )
    # The peak is the press's: where the gel is sunk at least half the simulated peak.
    binning = estimator_settings(settings).depth_binning
    rows, cols = depth.shape
    truth_on_grid = truth.reshape(rows, binning, cols, binning).mean(axis=(1, 3))
    deepest = np.unravel_index(int(np.argmax(scipy.ndimage.gaussian_filter(depth, 1.0))), depth.shape)
    assert truth_on_grid[deepest] >= 0.5 * simulated, f"{optics}: the reconstructed peak is off the press"
