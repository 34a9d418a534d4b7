"""One simulated grasp: load curve, sensors, frames, record (motion: :mod:`teleop.sim.motion`).

The fingers close symmetrically from ``max_width_m`` at ``closing_speed_m_s``.
From first touch, the motor's closure c (the reported width's drop below the
object's extent between the two first-contact points) is taken up by

* each finger's contact: the gel layer's and the object's surface
  displacement at the first-contact point (BEM or Hertz, :mod:`contact`);
* the object's bulk: uniaxial compression F L / (E A) of its extent L over its
  mean cross-section A, on top of the local contact;
* the fingers bending open by F / k (``finger_stiffness_n_per_m``, drawn around
  the setting per grasp: the rig's linear correction is never exact).

The object's share (contact plus bulk) stiffens as it is compressed: a finite
body cannot be squeezed through itself, foam densifies. Its linear value X is
mapped to X_max (1 - exp(-X / X_max)) with X_max = (densification strain) x L,
so soft objects still reach the force target before the fingers meet.

With drawn contact mechanics (``mechanics``, ``teleop simulate --vary-contact``:
:mod:`teleop.sim.mechanics`) the gel layer, the object's Poisson's ratio, size and
local stiffness, and its non-linear laws are the draw's, and the record's provenance
keeps them in ``extra["mechanics"]``; without, everything is as above.

The squeeze stops when the force reaches the grasp's target (drawn per grasp,
up to ``target_force_n``; the gripper stalls on its force limit) or the
fingers close completely; the host holds ``hold_s`` after the grasp reports
done, then commands release and the fingers open at the same speed (record
events ``command_grasp``, ``grasp_done``: the stop, ``command_release``). Sensors
(:mod:`sensors`) sample the true force and motor width; the cameras image the
gel's own displacement, interpolated between contact solutions on a ladder of
force levels (linear in log force; measured against a 48-level ladder this departs
by up to 5 % of the local displacement near the moving contact edge, 40-170 um on
the benchmark objects, so the ladder is not thinned). Every frame of the record is
rendered; frames of the same gel (before touch, through the hold) share one clean
render and differ by their camera noise. The host keeps the streams from
``PRE_ROLL_S`` (or at least ``PRE_ROLL_READINGS`` load-cell readings, when longer) before its
load cell first reads a touch until ``POST_ROLL_S`` after it reads the release.

Operator-driven grasps (``operator="sim"``, ``teleop simulate --operator sim``) replace the
scripted motion by a :class:`~teleop.sim.operator.SimulatedOperator` closed loop, as the robot
node runs a leader-follower grasp: the operator commands a target width at
``teleop.operator.FOLLOW_RATE_HZ`` from the force it feels (the true force; it feels it late),
the commands reach the gripper :data:`~teleop.sim.motion.FOLLOW_LATENCY_S` later, and the fingers
follow the target at up to :data:`~teleop.operator.FOLLOW_SPEED_M_S`, force-capped at
``gripper.target_force_n`` (the load curve is solved up to that cap; the gripper stalls there).
When the operator releases, the fingers open as after a scripted grasp. Everything downstream
(load cell, width readings, frames, record window) is as for scripted grasps; the record has no
``grasp_done`` event (there is no discrete stop), its provenance says ``style="operator"`` and
keeps the operator's drawn style in ``extra["operator"]``. The pose, scene and finger stiffness
are drawn as for a scripted grasp first, so the same random stream gives the same object
placement in both styles.

Nothing of this module's internals goes into the record except the provenance
(source, seed, model); :class:`GraspTruth` carries them for previews and tests.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np

from teleop.catalogue import ObjectSpec
from teleop.errors import SimulationError
from teleop.record import FrameStream, GraspRecord, Label, Provenance, Samples
from teleop.settings import SensorSettings, Settings
from teleop.sim.contact import (
    Body,
    ContactSolution,
    Influence,
    gel_shear,
    hertz_contact,
    hertz_sphere,
    layer_stiffening,
    solve_contact,
)
from teleop.sim.mechanics import ContactMechanics
from teleop.sim.motion import operator_motion, scripted_motion
from teleop.sim.operator import SimulatedOperator
from teleop.sim.optics import OpticsRenderer
from teleop.sim.sensors import camera_times, gripper_width_readings, load_cell_readings
from teleop.sim.shapes import Pose, Scene, draw_pose, make_scene, object_size, object_texture
from teleop.sim.wedge_optics import procedural_background

__all__ = [
    "OPERATORS",
    "FingerMechanics",
    "GraspTruth",
    "LoadCurve",
    "contact_grid",
    "load_curve",
    "simulate_grasp",
]

TARGET_FORCE_FRACTION = (0.4, 1.0)  # of GripperSettings.target_force_n, per grasp
FINGER_STIFFNESS_SD = 0.1  # log-normal spread of the true finger stiffness around the setting
DENSIFICATION_STRAIN = {"foam": 0.8, "food": 0.6}
DEFAULT_DENSIFICATION_STRAIN = 0.5
FINGERS_MET_M = 1e-6  # a width this close to zero: the fingers met (an object too small to grasp)
RECORD_FORCE_N = 0.2  # the host's touch threshold for keeping a record
PRE_ROLL_S = 0.2
PRE_ROLL_READINGS = 8  # at least this many load-cell readings before the touch: 0.85 s at 10 Hz
POST_ROLL_S = 0.1
OPERATORS = ("script", "sim")  # who drives the fingers: the scripted grasp or the simulated operator
LOAD_LEVELS = 12
MIN_LEVEL_FORCE_N = 0.05
SOLVER_TOLERANCE = 1e-3
# Hertz is used only where its error against the layered BEM is below this
# (first-order layer estimate, texture, object curvature and pad edges).
HERTZ_TOLERANCE = 0.01


def contact_grid(sensor: SensorSettings, grid_px: int) -> tuple[tuple[int, int], tuple[float, float]]:
    """Contact-solver grid covering the sensor's image: (rows, cols) and cell size (m, m)."""
    rows, cols = sensor.image_shape
    cell = grid_px * sensor.pixel_pitch_m
    return (math.ceil(rows / grid_px), math.ceil(cols / grid_px)), (cell, cell)


def _gel_body(sensor: SensorSettings, gel_model: str) -> Body:
    """The gel as the contact solver sees it (``SimulationSettings.gel_model``)."""
    thickness = sensor.gel_thickness_m if gel_model == "layer" else None
    return Body(sensor.gel_modulus_pa, sensor.gel_poisson, thickness)


@dataclass(frozen=True)
class FingerMechanics:
    """One finger's contact over the force ladder.

    ``gel_m`` and ``object_m`` are the gel's and the object's displacement at the
    first-contact point (their sum is the finger's approach), per level.
    """

    finger: str
    solutions: tuple[ContactSolution, ...]
    gel_m: np.ndarray
    object_m: np.ndarray


@dataclass(frozen=True)
class LoadCurve:
    """Motor closure beyond first touch as a function of force, and its parts.

    All arrays run over the levels ``force_n`` (ascending, first 0).
    """

    force_n: np.ndarray
    closure_m: np.ndarray
    gel_m: np.ndarray  # both gels at the first-contact points
    object_m: np.ndarray  # the object: both contacts plus bulk, after densification (and drawn laws)
    object_linear_m: np.ndarray  # the same before them
    bulk_linear_m: np.ndarray  # bulk part of object_linear_m
    finger_m: np.ndarray  # finger bending F / k
    fingers: dict[str, FingerMechanics]
    model: str

    def force_at(self, closure_m: np.ndarray) -> np.ndarray:
        """Force (N) at motor closure (m); 0 before touch."""
        return np.interp(closure_m, self.closure_m, self.force_n, left=0.0)

    def level_weights(self, force_n: float) -> list[tuple[int, float]]:
        """(level index, weight) pairs giving a field at ``force_n`` from the levels' fields.

        Linear in log force between the two nearest levels; below the first
        level its field scaled as F^(2/3); none at zero force.
        """
        levels = self.force_n[1:]
        if force_n <= 0:
            return []
        if force_n <= levels[0]:
            return [(0, (force_n / levels[0]) ** (2.0 / 3.0))]
        if force_n >= levels[-1]:
            return [(len(levels) - 1, 1.0)]
        upper = int(np.searchsorted(levels, force_n))
        w = math.log(force_n / levels[upper - 1]) / math.log(levels[upper] / levels[upper - 1])
        return [(upper - 1, 1.0 - w), (upper, w)]

    def weights_at(self, force_n: np.ndarray) -> np.ndarray:
        """:meth:`level_weights` of each force as rows of an (N, levels) matrix."""
        weights = np.zeros((len(force_n), len(self.force_n) - 1))
        for row, force in zip(weights, force_n, strict=True):
            for level, w in self.level_weights(float(force)):
                row[level] = w
        return weights

    def gel_map(self, finger: str, force_n: float) -> np.ndarray:
        """The gel's displacement (m) on the contact grid at ``force_n`` (see :meth:`level_weights`)."""
        maps = [s.gel_displacement_m for s in self.fingers[finger].solutions]
        return sum((w * maps[i] for i, w in self.level_weights(force_n)), np.zeros_like(maps[0]))


def _hertz_applies(obj: ObjectSpec, size: tuple[float, float, float], first_contact_rc: tuple[int, int],
                   max_force_n: float, gel: Body, body: Body,
                   grid: tuple[tuple[int, int], tuple[float, float]]) -> bool:
    """Whether Hertz is within HERTZ_TOLERANCE of the layered BEM for one finger's contact."""
    if obj.shape != "sphere":
        return False
    radius = size[0] / 2
    e_star = 1.0 / (gel.compliance_per_pa + body.compliance_per_pa)
    a = float(hertz_sphere(max_force_n, radius_m=radius, e_star_pa=e_star)[0])
    small_approach = float(hertz_sphere(0.1 * max_force_n, radius_m=radius, e_star_pa=e_star)[1])
    (rows, cols), cell = grid
    row, col = first_contact_rc
    edge_m = min(row * cell[0], (rows - 1 - row) * cell[0], col * cell[1], (cols - 1 - col) * cell[1])
    return (a <= HERTZ_TOLERANCE * 10 * radius  # small strain: a <= R / 10
            and layer_stiffening(a, gel=gel, obj=body) <= HERTZ_TOLERANCE
            and object_texture(obj) <= HERTZ_TOLERANCE * small_approach
            and edge_m >= 3 * a)


def load_curve(obj: ObjectSpec, scene: Scene, *, sensors: dict[str, SensorSettings], grid_px: int,
               max_force_n: float, finger_stiffness_n_per_m: float,
               size: tuple[float, float, float] | None = None, gel_model: str = "layer",
               mechanics: ContactMechanics | None = None) -> LoadCurve:
    """Solve both contacts on a ladder of forces up to ``max_force_n`` and assemble the closure.

    Parameters
    ----------
    obj : ObjectSpec
    scene : Scene
        Gap profiles of both fingers (from :func:`~teleop.sim.shapes.make_scene`).
    sensors : dict finger -> SensorSettings
        The two fingers' sensors (gel layer and image grid).
    grid_px : int
        Contact-solver cell size in image pixels.
    max_force_n : float
        The top of the ladder (the grasp's target force).
    finger_stiffness_n_per_m : float
        True stiffness of the finger pair.
    gel_model : {"layer", "half-space"}
        The gel as a bonded layer of its thickness, or as a half-space.
    mechanics : ContactMechanics, optional
        Drawn contact mechanics (module notes); only with the ``"layer"`` gel model.

    Raises
    ------
    SimulationError
        A contact solve did not converge (its reason is in the message), or ``mechanics``
        came with the half-space gel model.
    """
    if mechanics is not None and gel_model != "layer":
        raise SimulationError(f"drawn contact mechanics replace the gel model, and gel_model {gel_model!r} is the "
                              "held-out one: expected gel_model 'layer' with mechanics")
    size = object_size(obj) if size is None else size
    body = Body(obj.modulus_pa, obj.poisson) if mechanics is None else mechanics.object_body(obj)
    gels = {finger: _gel_body(sensor, gel_model) if mechanics is None else mechanics.gel_body(sensor)
            for finger, sensor in sensors.items()}
    grids = {finger: contact_grid(sensor, grid_px) for finger, sensor in sensors.items()}
    levels = np.geomspace(min(MIN_LEVEL_FORCE_N, max_force_n / 10), max_force_n, LOAD_LEVELS)
    use_hertz = all(_hertz_applies(obj, size, scene.first_contact_rc[f], max_force_n, gels[f], body, grids[f])
                    for f in sensors)
    model = "hertz" if use_hertz else ("bem-layer" if gel_model == "layer" else "bem-half-space")

    fingers = {}
    for finger in sensors:
        gap = scene.gap_m[finger]
        first = scene.first_contact_rc[finger]
        shape, cell = grids[finger]
        if gap.shape != shape:
            raise SimulationError(f"finger {finger!r}: gap grid {gap.shape} does not match the sensor's {shape}")
        solutions = []
        if use_hertz:
            solutions = [hertz_contact(f, shape=shape, cell_m=cell, centre_rc=first, radius_m=size[0] / 2,
                                       gel=gels[finger], obj=body) for f in levels]
        else:
            try:
                influence = Influence(shape, cell, gel=gels[finger], obj=body)
            except ValueError as exc:
                raise SimulationError(f"sensor {finger!r} with grid_px {grid_px}: {exc}") from exc
            previous = None
            for force in levels:
                solution = solve_contact(gap, influence, force_n=float(force), tolerance=SOLVER_TOLERANCE,
                                         initial_pressure_pa=previous)
                if not solution:
                    raise SimulationError(
                        f"object {obj.name!r}, finger {finger!r}: contact at {force:.3g} N failed: {solution.reason}"
                    )
                solutions.append(solution)
                previous = solution.pressure_pa
        gel_m = np.array([s.gel_displacement_m[first] for s in solutions])
        fingers[finger] = FingerMechanics(finger, tuple(solutions), gel_m,
                                          np.array([s.approach_m for s in solutions]) - gel_m)

    bulk = levels * scene.extent_m / (obj.modulus_pa * scene.cross_section_m2)
    object_linear = sum(m.object_m for m in fingers.values()) + bulk
    strain = DENSIFICATION_STRAIN.get(obj.material, DEFAULT_DENSIFICATION_STRAIN)
    if mechanics is None:
        limit = strain * scene.extent_m
        object_m = limit * -np.expm1(-object_linear / limit)
    else:
        object_m = mechanics.object_response(object_linear, extent_m=scene.extent_m, densification_strain=strain)
    gel_m = sum(m.gel_m for m in fingers.values())
    finger_m = levels / finger_stiffness_n_per_m
    closure = gel_m + object_m + finger_m

    def with_zero(values: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], values])

    closure = np.maximum.accumulate(with_zero(closure))  # guard the inverse against solver noise
    return LoadCurve(
        force_n=with_zero(levels), closure_m=closure, gel_m=with_zero(gel_m), object_m=with_zero(object_m),
        object_linear_m=with_zero(object_linear), bulk_linear_m=with_zero(bulk), finger_m=with_zero(finger_m),
        fingers=fingers, model=model,
    )


@dataclass(frozen=True)
class GraspTruth:
    """The simulator's ground truth of one grasp (never written to the record).

    ``target_force_n`` is the force the grasp squeezed to (an operator grasp: the peak force it
    reached); ``stall_s`` when the fingers stopped at it (an operator grasp: when the force first
    peaked); ``release_s`` when the release was commanded.
    """

    size_m: tuple[float, float, float]
    pose: Pose
    scene: Scene
    curve: LoadCurve
    target_force_n: float
    finger_stiffness_n_per_m: float
    t_s: np.ndarray  # fine time grid
    force_n: np.ndarray  # true normal force
    motor_width_m: np.ndarray  # what the gripper would report without noise or latency
    touch_s: float
    stall_s: float
    release_s: float
    peak_gel_m: dict[str, np.ndarray] = field(default_factory=dict)  # image grid, at peak force
    operator: SimulatedOperator | None = None  # who drove an operator grasp (None: scripted)

    @property
    def tip_width_m(self) -> np.ndarray:
        """True distance between the undeformed gel surfaces (the fingers bend open by F / k)."""
        return self.motor_width_m + self.force_n / self.finger_stiffness_n_per_m


@functools.lru_cache(maxsize=8)
def _procedural_background(sensor: SensorSettings) -> np.ndarray:
    """The sensor's no-contact frame: fixed per sensor identity, like its dust and lighting."""
    seed = zlib.crc32(f"{sensor.model}/{sensor.finger}/{sensor.serial}/background".encode())
    return procedural_background(sensor, rng=np.random.default_rng(seed))


def _to_image(field_grid: np.ndarray, sensor: SensorSettings, grid_px: int) -> np.ndarray:
    """Contact grid -> the sensor's image grid (bicubic, centred crop), float32; channels ride along."""
    rows, cols = sensor.image_shape
    up = cv2.resize(field_grid.astype(np.float32), (field_grid.shape[1] * grid_px, field_grid.shape[0] * grid_px),
                    interpolation=cv2.INTER_CUBIC)
    r0, c0 = (up.shape[0] - rows) // 2, (up.shape[1] - cols) // 2
    return up[r0:r0 + rows, c0:c0 + cols]


def simulate_grasp(obj: ObjectSpec, *, settings: Settings, rng: np.random.Generator,
                   seed: int | None = None, background: dict[str, np.ndarray] | None = None,
                   operator: str = "script", mechanics: ContactMechanics | None = None,
                   force_n: float | None = None) -> tuple[GraspRecord, GraspTruth]:
    """Simulate one labelled grasp of ``obj``.

    Parameters
    ----------
    obj : ObjectSpec
    settings : Settings
        Exactly two sensors (the first at the -x finger); gripper, load cell and
        simulation settings.
    rng : Generator
        Every random draw of this grasp comes from it: same state, same record.
    seed : int, optional
        Stored in the record's provenance.
    background : dict finger -> raw BGR uint8 frame, optional
        No-contact frames for the cameras (default: as SimulationSettings says).
    operator : {"script", "sim"}
        Who drives the fingers: the paper's scripted grasp, or a
        :class:`~teleop.sim.operator.SimulatedOperator` drawn from ``rng`` in a leader-follower
        loop (module notes; the record's ``provenance.style`` is ``"operator"``).
    mechanics : ContactMechanics, optional
        Drawn contact mechanics (:mod:`teleop.sim.mechanics`; the settings' gel model must be
        ``"layer"``); the record's ``provenance.extra["mechanics"]`` keeps them and the size used.
    force_n : float, optional
        A scripted grasp commanded to this force (N) squeezes to it, not to a drawn share of
        ``gripper.target_force_n`` (the draw is still made: the rest of the grasp stays the same).

    Returns
    -------
    GraspRecord, GraspTruth
        The record carries the settings' sensors and gripper (the rig it was simulated on).

    Raises
    ------
    SimulationError
        The settings do not have two sensors, the object does not fit the
        gripper, the fingers closed on each other before the force target (an
        object too small to grasp), or a contact solve failed; ``obj`` is not an ObjectSpec,
        ``settings`` not Settings, ``rng`` not a numpy Generator or ``force_n`` not a finite
        number > 0.
    """
    if not isinstance(obj, ObjectSpec):
        raise SimulationError(f"obj: expected an ObjectSpec (teleop.catalogue.load_catalogue), got {type(obj).__name__}")
    if not isinstance(settings, Settings):
        raise SimulationError(f"settings: expected Settings (teleop.settings.load_settings), got {type(settings).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise SimulationError(f"rng: expected a numpy Generator (numpy.random.default_rng(seed)), got {rng!r}")
    if force_n is not None and (isinstance(force_n, bool) or not isinstance(force_n, numbers.Real)
                                or not math.isfinite(force_n) or force_n <= 0):
        raise SimulationError(f"force_n = {force_n!r}: expected None or a finite number > 0 (N)")
    if operator not in OPERATORS:
        raise SimulationError(f"operator {operator!r}: expected one of {', '.join(OPERATORS)}")
    if len(settings.sensors) != 2:
        raise SimulationError(
            f"the grasp simulator needs exactly two sensors (one per finger); settings have "
            f"{[s.finger for s in settings.sensors]}"
        )
    gripper, sim = settings.gripper, settings.simulation
    sensors = {s.finger: s for s in settings.sensors}
    fingers = tuple(sensors)
    first_sensor = settings.sensors[0]
    size = object_size(obj)
    if mechanics is not None:
        size = mechanics.object_size(obj, size, max_width_m=gripper.max_width_m)
    pose = draw_pose(obj, size, rng=rng, max_width_m=gripper.max_width_m, pad_m=first_sensor.pad_size_m)
    shape, cell = contact_grid(first_sensor, sim.grid_px)
    if any(contact_grid(s, sim.grid_px)[0] != shape or not math.isclose(s.pixel_pitch_m, first_sensor.pixel_pitch_m,
                                                                       rel_tol=1e-3) for s in settings.sensors):
        raise SimulationError("the two sensors must share the image grid and pixel pitch")
    scene = make_scene(obj, pose, shape=shape, cell_m=cell, fingers=fingers, rng=rng, size=size)
    if scene.extent_m >= gripper.max_width_m:
        raise SimulationError(f"object {obj.name!r} is {scene.extent_m:.3f} m wide here: "
                              f"more than the gripper opens ({gripper.max_width_m} m)")
    # Drawn in both styles, so that one random stream gives one placement and one pair of fingers.
    target = gripper.target_force_n * rng.uniform(*TARGET_FORCE_FRACTION)
    target = target if force_n is None else force_n
    stiffness = gripper.finger_stiffness_n_per_m * math.exp(rng.normal(0.0, FINGER_STIFFNESS_SD))
    driver = None
    if operator == "sim":
        driver = SimulatedOperator(rng, max_width_m=gripper.max_width_m, max_force_n=gripper.target_force_n)
    curve = load_curve(obj, scene, sensors=sensors, grid_px=sim.grid_px,
                       max_force_n=target if driver is None else gripper.target_force_n,
                       finger_stiffness_n_per_m=stiffness, size=size, gel_model=sim.gel_model, mechanics=mechanics)
    if driver is None:
        motion = scripted_motion(curve, scene, gripper, rng)
    else:
        motion = operator_motion(curve, scene, gripper, driver, rng)
        target = float(motion.force_n.max())
    t, force, motor_width = motion.t_s, motion.force_n, motion.motor_width_m
    release_s = motion.release_s
    if float(curve.closure_m[-1]) >= scene.extent_m and float(motor_width.min()) <= FINGERS_MET_M:
        # The fingers met before the force cap: the grasp only touched the object, whatever its label says.
        raise SimulationError(f"object {obj.name!r} is too small to grasp: {scene.extent_m * 1e3:.3g} mm wide here, "
                              f"the fingers closed on each other at {float(force.max()):.3g} N, short of the "
                              f"{curve.force_n[-1]:.3g} N force cap")

    # What the host keeps: from just before its load cell reads a touch to just after it reads the release.
    readings = load_cell_readings(t, force, load_cell=settings.load_cell, sim=sim, rng=rng,
                                  start_s=float(t[0]), end_s=float(t[-1]))
    threshold = min(RECORD_FORCE_N, 0.5 * float(force.max()))
    above = np.flatnonzero(readings.value > threshold)
    # Half a period more than the readings asked for: the cell's stamps jitter, and a window of exactly
    # PRE_ROLL_READINGS periods holds one reading fewer about half the time.
    pre_roll_s = max(PRE_ROLL_S, (PRE_ROLL_READINGS + 0.5) / settings.load_cell.sample_rate_hz)
    start_s = (readings.t_s[above[0]] if above.size else motion.touch_s) - pre_roll_s
    after = np.flatnonzero((readings.t_s > release_s) & (readings.value <= threshold))
    end_s = (readings.t_s[after[0]] if after.size else motion.lost_s) + POST_ROLL_S
    keep = (readings.t_s >= start_s) & (readings.t_s <= end_s)
    force_samples = Samples(readings.t_s[keep], readings.value[keep])
    width_samples = gripper_width_readings(t, motor_width, gripper=gripper, sim=sim, rng=rng,
                                           start_s=start_s, end_s=end_s)

    streams = []
    peak = {}
    for finger, sensor in sensors.items():
        capture_s, stamp_s = camera_times(sensor=sensor, sim=sim, rng=rng, start_s=start_s, end_s=end_s)
        camera_background = (background or {}).get(finger)
        if camera_background is None and not sim.background and sensor.optics == "wedge":
            camera_background = _procedural_background(sensor)  # table optics: the real sensor's own
        camera = OpticsRenderer(sensor, sim=sim, rng=rng.spawn(1)[0], background=camera_background)
        # Height and in-plane displacement on the image grid at each force level; both are linear
        # in the gel's displacement, so a frame's are the same weighted sum of the levels'.
        gel = np.stack([s.gel_displacement_m for s in curve.fingers[finger].solutions])
        shear = gel_shear(gel, cell_m=cell, thickness_m=sensor.gel_thickness_m)
        levels = _to_image(np.concatenate([gel[..., None], shear], axis=-1).transpose(1, 2, 0, 3)
                           .reshape(*gel.shape[1:], -1), sensor, sim.grid_px)
        levels = levels.reshape(*levels.shape[:2], len(gel), 3).transpose(2, 0, 1, 3)
        encoded = camera.capture_series(levels[..., 0], curve.weights_at(np.interp(capture_s, t, force)),
                                        shear_m=levels[..., 1:])
        peak[finger] = _to_image(curve.gel_map(finger, float(force.max())), sensor, sim.grid_px)
        streams.append(FrameStream(finger=finger, t_s=stamp_s, encoded=tuple(encoded), encoding="jpeg",
                                   jpeg_quality=sim.jpeg_quality,
                                   shape=(sensor.raw_height_px, sensor.raw_width_px, 3)))

    extra = {}
    if driver is not None:
        extra["operator"] = json.loads(json.dumps({  # as the record reads it back
            **dataclasses.asdict(driver.style), "description": driver.style.describe()}))
    if mechanics is not None:
        extra["mechanics"] = {**mechanics.provenance(), "size_m": list(size)}
    provenance = Provenance(source="simulated", seed=seed, model=curve.model,
                            style="script" if driver is None else "operator", extra=extra)
    record = GraspRecord(
        sensors=settings.sensors,
        gripper=gripper,  # as an exported session's: the estimator reads the grasp on its rig
        frames=tuple(streams),
        force_n=force_samples,
        width_m=width_samples,
        provenance=provenance,
        label=Label(object_name=obj.name, modulus_pa=obj.modulus_pa, material=obj.material, shape=obj.shape),
        events=motion.events,
    )
    truth = GraspTruth(
        size_m=size, pose=pose, scene=scene, curve=curve, target_force_n=target,
        finger_stiffness_n_per_m=stiffness, t_s=t, force_n=force, motor_width_m=motor_width,
        touch_s=motion.touch_s, stall_s=motion.stall_s, release_s=release_s, peak_gel_m=peak, operator=driver,
    )
    return record, truth
