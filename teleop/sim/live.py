"""Live simulation of an operator-driven grasp: the object squeezed as the fingers move.

A scripted grasp is simulated whole, ahead of time (:func:`teleop.sim.grasp.simulate_grasp`);
an operator's grasp cannot be, since nobody knows ahead where the operator will move the
fingers. This module splits the same physics in two:

* :func:`prepare_object` does the slow part once per object, ahead of the grasp: the pose
  and scene, the load curve up to the settings' maximum force (``gripper.target_force_n``),
  each finger's gel displacement at the curve's force levels on the image grid, and each
  finger's camera (:class:`~teleop.sim.optics.OpticsRenderer`). It reuses the building
  blocks of :mod:`teleop.sim.grasp`, so a live grasp squeezes the object a scripted one does.
* :class:`Motor` and :meth:`LiveObject.force_at` / :meth:`LiveObject.frame` are the fast part,
  in real time: the motor's width moves toward its commanded target at the commanded speed
  and stalls where the contact's force reaches the maximum (the fingers never exceed it);
  the force is the load curve's at the motor's closure; a frame (about 2 ms) shows the gel
  at the force of its capture time.

The sensors' sampling, latency and noise in real time are the simulated devices' job
(:mod:`teleop.devices.live_sim`).
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass

import numpy as np

from teleop.catalogue import ObjectSpec
from teleop.errors import SimulationError
from teleop.settings import Settings
from teleop.sim.contact import gel_shear
from teleop.sim.grasp import (
    FINGER_STIFFNESS_SD,
    LoadCurve,
    _procedural_background,
    _to_image,
    contact_grid,
    load_curve,
)
from teleop.sim.optics import OpticsRenderer
from teleop.sim.shapes import Scene, draw_pose, make_scene, object_size

__all__ = ["HISTORY_S", "LiveObject", "Motor", "prepare_object"]

HISTORY_S = 2.0  # the motor remembers its motion this far back (s): sensors sample the recent past


@dataclass(frozen=True)
class LiveObject:
    """One object prepared for a live grasp (see :func:`prepare_object`).

    Attributes
    ----------
    name : str
        The object's catalogue name.
    scene : Scene
        Its pose between the fingers (``extent_m``: its width there, m).
    curve : LoadCurve
        Force against motor closure beyond first touch, up to ``max_force_n``.
    max_force_n : float
        The most force the fingers apply (N): the settings' maximum grasp force.
    levels : dict finger -> (heights, shears)
        The gel's indentation (m, (K, H, W)) and in-plane displacement (m, (K, H, W, 2)) on the
        sensor's image grid at each of the curve's K force levels.
    cameras : dict finger -> OpticsRenderer
        Each finger's simulated camera (its own noise stream).
    """

    name: str
    scene: Scene
    curve: LoadCurve
    max_force_n: float
    levels: dict[str, tuple[np.ndarray, np.ndarray]]
    cameras: dict[str, OpticsRenderer]

    @property
    def extent_m(self) -> float:
        """The object's width between the fingers' first-contact points (m)."""
        return float(self.scene.extent_m)

    @property
    def stall_width_m(self) -> float:
        """The motor width (m) at which the force reaches :attr:`max_force_n`, or 0 when the
        fingers meet before it does."""
        return max(0.0, self.extent_m - float(self.curve.closure_m[-1]))

    def force_at(self, width_m: float) -> float:
        """True normal force (N) at motor width ``width_m`` (m); 0 before touch."""
        return float(self.curve.force_at(np.array([self.extent_m - width_m]))[0])

    def frame(self, finger: str, force_n: float) -> bytes:
        """One JPEG frame of ``finger``'s camera with the gel pressed at ``force_n`` (N)."""
        heights, shears = self.levels[finger]
        weights = self.curve.weights_at(np.array([force_n]))
        return self.cameras[finger].capture_series(heights, weights, shear_m=shears)[0]


def prepare_object(obj: ObjectSpec, *, settings: Settings, rng: np.random.Generator) -> LiveObject:
    """Pose ``obj`` between the fingers and solve everything a live grasp of it needs (seconds).

    Parameters
    ----------
    obj : ObjectSpec
    settings : Settings
        Two sensors, the gripper (``max_width_m``; ``target_force_n``: the force ladder's top)
        and the simulation settings, as for :func:`~teleop.sim.grasp.simulate_grasp`.
    rng : Generator
        The pose, the finger stiffness and the cameras' noise come from it.

    Raises
    ------
    SimulationError
        Not two sensors, the object does not fit the gripper, or a contact solve failed.
    """
    if len(settings.sensors) != 2:
        raise SimulationError(f"a live grasp needs exactly two sensors (one per finger); settings have "
                              f"{[s.finger for s in settings.sensors]}")
    gripper, sim = settings.gripper, settings.simulation
    sensors = {s.finger: s for s in settings.sensors}
    first = settings.sensors[0]
    size = object_size(obj)
    pose = draw_pose(obj, size, rng=rng, max_width_m=gripper.max_width_m, pad_m=first.pad_size_m)
    shape, cell = contact_grid(first, sim.grid_px)
    scene = make_scene(obj, pose, shape=shape, cell_m=cell, fingers=tuple(sensors), rng=rng, size=size)
    if scene.extent_m >= gripper.max_width_m:
        raise SimulationError(f"object {obj.name!r} is {scene.extent_m:.3f} m wide here: "
                              f"more than the gripper opens ({gripper.max_width_m} m)")
    stiffness = gripper.finger_stiffness_n_per_m * math.exp(rng.normal(0.0, FINGER_STIFFNESS_SD))
    curve = load_curve(obj, scene, sensors=sensors, grid_px=sim.grid_px, max_force_n=gripper.target_force_n,
                       finger_stiffness_n_per_m=stiffness, size=size, gel_model=sim.gel_model)
    levels, cameras = {}, {}
    for finger, sensor in sensors.items():
        gel = np.stack([s.gel_displacement_m for s in curve.fingers[finger].solutions])
        shear = gel_shear(gel, cell_m=cell, thickness_m=sensor.gel_thickness_m)
        stacked = _to_image(np.concatenate([gel[..., None], shear], axis=-1).transpose(1, 2, 0, 3)
                            .reshape(*gel.shape[1:], -1), sensor, sim.grid_px)
        stacked = stacked.reshape(*stacked.shape[:2], len(gel), 3).transpose(2, 0, 1, 3)
        levels[finger] = (np.ascontiguousarray(stacked[..., 0]), np.ascontiguousarray(stacked[..., 1:]))
        background = _procedural_background(sensor) if not sim.background and sensor.optics == "wedge" else None
        cameras[finger] = OpticsRenderer(sensor, sim=sim, rng=rng.spawn(1)[0], background=background)
    return LiveObject(obj.name, scene, curve, gripper.target_force_n, levels, cameras)


class Motor:
    """The fingers' motor width in real time: toward a target at a speed, never below a stall width.

    Each command starts a straight motion from where the motor is; the motion of the last
    :data:`HISTORY_S` seconds is kept, so :meth:`width_at` answers for the recent past too
    (a sensor sampled then). Thread-safe.

    Parameters
    ----------
    width_m : float
        Width at ``t_s`` (m), at rest.
    t_s : float
        Clock time of that width (s).
    stall_width_m : float
        The motor closes no further than this (m): there the object pushes back with the
        maximum force.
    """

    def __init__(self, width_m: float, t_s: float, *, stall_width_m: float):
        self.stall_width_m = float(stall_width_m)
        width = max(float(width_m), self.stall_width_m)
        # Segments (start_s, from_m, to_m, speed_m_s), in time order.
        self._segments: list[tuple[float, float, float, float]] = [(float(t_s), width, width, 1.0)]
        self._lock = threading.Lock()

    @staticmethod
    def _along(segment: tuple[float, float, float, float], t_s: float) -> float:
        start_s, from_m, to_m, speed = segment
        travelled = speed * max(0.0, t_s - start_s)
        return to_m if abs(to_m - from_m) <= travelled else from_m + math.copysign(travelled, to_m - from_m)

    def width_at(self, t_s: float) -> float:
        """The motor's width (m) at clock time ``t_s`` (s): now, or within the kept history."""
        with self._lock:
            index = max(0, bisect.bisect_right(self._segments, t_s, key=lambda s: s[0]) - 1)
            return self._along(self._segments[index], t_s)

    def target_m(self) -> float:
        """Where the motor is heading (m), the stall width applied."""
        with self._lock:
            return self._segments[-1][2]

    def command(self, to_m: float, speed_m_s: float, now_s: float) -> float:
        """Head for ``to_m`` (m) at ``speed_m_s`` (m/s) from now; returns when it arrives (clock s)."""
        if not (math.isfinite(to_m) and speed_m_s > 0):
            raise SimulationError(f"motor command to {to_m!r} m at {speed_m_s!r} m/s: expected a finite "
                                  "width and a speed > 0")
        here = self.width_at(now_s)
        to_m = max(float(to_m), self.stall_width_m)
        with self._lock:
            self._segments.append((now_s, here, to_m, float(speed_m_s)))
            while len(self._segments) > 1 and self._segments[1][0] < now_s - HISTORY_S:
                self._segments.pop(0)
        return now_s + abs(to_m - here) / speed_m_s

    def stop(self, now_s: float) -> None:
        """Hold the width the motor has now."""
        here = self.width_at(now_s)
        self.command(here, 1.0, now_s)

    def stalled(self, now_s: float) -> bool:
        """Whether the motor stands at its stall width (the force at its maximum)."""
        return self.width_at(now_s) <= self.stall_width_m + 1e-9 and self.stall_width_m > 0
