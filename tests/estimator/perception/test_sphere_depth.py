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

Status (seed 0, binning 2, the shipped calibrations fitted with the default flat-gel weight
``flat_weight = 15``, see :mod:`estimator.perception.calibration_fit`): the criterion holds on
the ``wedge`` optics; the two table optics are skipped with the reason. Simulated peak;
reconstructed peak (ratio); reconstruction at the simulated peak's position (ratio); in
brackets the ratios with the calibrations fitted before the weight (every flat pixel counted
once):

* ``wedge``          0.255 mm; 0.208 mm (0.82) [0.67], 4.8 mm off centre; 0.193 mm (0.76)
                     [0.62]
* ``gelsight``       0.264 mm; 0.092 mm (0.35) [0.28], 6.7 mm off centre near the pad's top
                     edge; 0.030 mm (0.11) [0.09]
* ``gelsight_mini``  0.478 mm; 0.084 mm (0.18) [0.17], 7.0 mm off centre near the top edge,
                     off the press; 0.010 mm (0.02) [0.01]

Two causes, measured on these presses (on the full-resolution grid):

1. Small slopes are read too small (all optics). A slope below ~0.03 (Wedge) or ~0.05
   (GelSight tables) changes the colour by less than the table's centre bin (+-0.021
   relative change: ``relative_range`` 1.0 over 48 bins), so it reads as flat. The bins
   next to it used to be pulled towards zero as well, by the flat-gel labels, which
   outnumber the on-ball labels of a 2 mm ball 45-210 to 1: projected on the true gradient
   the unweighted table returned 0.15 / 0.70 / 0.86 of slopes in 0.02-0.05 / 0.05-0.1 /
   0.1-0.2 on the Wedge, and 0.03 / 0.17 / 0.27 (R1.5) and 0.04 / 0.07 / 0.19 (Mini) on the
   table optics, and the Wedge's cap came out as a flat plateau of ~0.16 mm. The flat-gel
   weight (the flat labels together count 15 times the on-ball ones) weakens that pull;
   the centre bin remains. Weights tried (flat : on-ball; peak ratio wedge / gelsight /
   mini): unweighted 0.67 / 0.28 / 0.17; 30: 0.78 / 0.31 / 0.17; 20: 0.80 / 0.33 / 0.17;
   15: 0.82 / 0.35 / 0.18; 10: 0.84 / 0.37 / 0.18; 3: 0.88 / 0.40 / 0.19; 1: 0.92 / 0.43 /
   0.20; 0.1: 1.00 / 0.50 / 0.24. Lighter flat weights raise the depth read from a frame
   without contact: here (three no-press captures against the reference; RMS / max) on the
   Wedge 0.01 / 1.0 um unweighted, 0.06 / 4.3 um at 15, 0.29 / 6.2 um at 1, and on the Mini
   0.12 / 7.9, 0.20 / 10.1 and 0.66 / 17.5 um; on a real GelSight frame with 2 grey levels
   of noise (test_depth.py) the maximum is 15 um unweighted, 17 um at 15, 20 um at 10 and
   59 um at 1, against the settings' 20 um depth resolution, which sets the default.
2. The contact is wider than the GelSight pads (both table optics). Their pad is
   17.7 x 13.0 mm and the contact radius about 8 mm, so the gel is sunk at the top and
   bottom edges (0.19 mm on the R1.5; 0.46 mm on the Mini, whose left and right edges are
   sunk 0.2 mm too), where the Poisson solve anchors the depth at zero: even the exact
   gradients integrate to only 0.77 (R1.5) and 0.36 (Mini) of the peak. (The Wedge's exact
   gradients give 1.07: its border sits on the ~0.01 mm bulge around the contact.) No
   table can bring these two within 20 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage

from estimator.features import contact_features
from estimator.measure import calibration_path
from estimator.perception import load_calibration, reconstruct_depth
from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration
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
# (module notes). Remove an entry once its reconstruction meets the criterion.
NOT_MET = {
    "gelsight": "reads 0.35 of the peak, off the press centre: the contact is wider than the "
                "13 mm pad, whose sunk edges the depth is anchored to (exact gradients give 0.77), "
                "and slopes below ~0.05 fall in the calibration table's centre bin",
    "gelsight_mini": "reads 0.18 of the peak, off the press: the contact sinks almost the whole "
                     "pad border, where the depth is anchored (exact gradients give 0.36), and "
                     "slopes below ~0.05 fall in the calibration table's centre bin",
}


def _optics_params(optics_names):
    return [pytest.param(name, marks=pytest.mark.skip(reason=f"criterion not met: {NOT_MET[name]}"))
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
                      modulus_pa=sensor.gel_modulus_pa, poisson=settings.estimator.object_poisson,
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
    binning = settings.estimator.depth_binning
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
    binning = settings.estimator.depth_binning
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
    binning = settings.estimator.depth_binning
    rows, cols = depth.shape
    truth_on_grid = truth.reshape(rows, binning, cols, binning).mean(axis=(1, 3))
    deepest = np.unravel_index(int(np.argmax(scipy.ndimage.gaussian_filter(depth, 1.0))), depth.shape)
    assert truth_on_grid[deepest] >= 0.5 * simulated, f"{optics}: the reconstructed peak is off the press"
