"""Randomized rigs: what differs between real set-ups, drawn per simulated grasp.

A model trained on one simulated rig learns that rig: its gel, its fingers, its
clocks. ``teleop simulate --randomize-rig`` draws a rig for every grasp from
:class:`RigSpread` (one documented place for the distribution) with :func:`draw`.

What the lab knows and what is true
-----------------------------------
A drawn :class:`Rig` is two :class:`~teleop.settings.Settings`:

``known``
    What a lab would know of its rig, and so what the record carries
    (:meth:`Rig.record`: ``record.sensors`` and ``record.gripper``) and what the
    estimator may use. The gels are the catalogue's (a lab knows its gel only to
    the datasheet); the finger stiffness is the value the lab measured and
    configured; rates, the closing speed and the target force are what it set.
``true``
    What the physics and the rendering use: ``known`` with each gel's modulus and
    thickness drawn within manufacturing tolerance. The finger stiffness's
    calibration error is not drawn here: the grasp simulator already bends the
    fingers by a stiffness drawn log-normally (s.d. 10 %,
    ``teleop.sim.grasp.FINGER_STIFFNESS_SD``) around the configured value for every
    grasp, with or without this option; a second error on top would stack.

With ``vary_gel`` (``teleop simulate --vary-gel``) the gel itself is drawn first, as
another sensor's datasheet would give it (both fingers alike, and ``known`` carries it):
GelSight-type sensors are cast from different silicones in different thicknesses
(the simulated Wedge's 275 kPa and 3 mm, the R1.5's 250 kPa, softer and thicker gels
on others). The tolerances then apply around the drawn gel.

Noise, rates and latencies are simply what the devices do: both settings carry
them. The record's provenance (``extra["rig"]``, :meth:`Rig.provenance`) keeps the
true values for later analysis; no estimator reads it.

Ranges (:data:`RIG_SPREAD`)
---------------------------
=======================  ==========================  ===========================================
quantity                 range                       why
=======================  ==========================  ===========================================
gel modulus              catalogue x [0.85, 1.15]    silicone cure: +-15 % batch to batch, per gel
gel thickness            catalogue x [0.90, 1.10]    cast layer: +-10 %, per gel
finger stiffness         20-500 kN/m, log-uniform    printed soft fingers to stiff metal ones
target force             5-30 N, uniform             gentle to the shipped 30 N (each grasp then
                                                     squeezes to 40-100 % of it, as without rigs)
closing speed            20-75 mm/s, log-uniform     about half to twice the default 37.5 mm/s
force noise              0.005-0.06 N, log-uniform   a well-shielded HX711 to a noisy bridge
width noise              5-60 um, log-uniform        around the default 20 um
width read latency       0.03-0.15 s, uniform        franky round trips on different networks
camera pixel noise       1-4 levels, uniform         around the default 2 levels
camera rate              25-60 Hz, uniform           USB webcams and Pi cameras; both fingers alike
load-cell rate           10 or 80 Hz, either         the HX711's two rates (RATE pin)
width read rate          5-30 Hz, log-uniform        polling budgets of the host
camera offset            0-30 ms, uniform            USB/MJPG capture latency of the cameras
illumination gain        0.7-1.3, uniform            LED current and ageing
gel (``vary_gel``)       120-400 kPa, log-uniform;   silicones of GelSight-type gels (Shore 00
                         2.5-4.5 mm, uniform         10-40) cast 2.5 to 4.5 mm thick
=======================  ==========================  ===========================================
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from teleop.record import GraspRecord
from teleop.settings import Settings

__all__ = ["RIG_SPREAD", "Rig", "RigSpread", "draw"]

Range = tuple[float, float]


@dataclass(frozen=True)
class RigSpread:
    """How rigs differ: every range a rig is drawn from (see the module notes for why).

    ``*_tolerance`` are relative half-widths around the catalogue value (uniform);
    the other ranges are absolute, uniform unless :data:`LOG_UNIFORM` names them.
    """

    gel_modulus_tolerance: float = 0.15
    gel_thickness_tolerance: float = 0.10
    finger_stiffness_n_per_m: Range = (2.0e4, 5.0e5)
    target_force_n: Range = (5.0, 30.0)
    closing_speed_m_s: Range = (0.02, 0.075)
    force_noise_n: Range = (0.005, 0.06)
    width_noise_m: Range = (5e-6, 6e-5)
    width_latency_s: Range = (0.03, 0.15)
    camera_noise: Range = (1.0, 4.0)
    camera_hz: Range = (25.0, 60.0)
    load_cell_hz: tuple[float, ...] = (10.0, 80.0)  # one of them, each as likely
    width_read_hz: Range = (5.0, 30.0)
    # Frames stamped on arrival over USB; a larger offset a rig measures and corrects (issue 22).
    camera_offset_s: Range = (0.0, 0.03)
    illumination_gain: Range = (0.7, 1.3)
    # Only with vary_gel: another sensor's datasheet gel.
    gel_modulus_pa: Range = (1.2e5, 4.0e5)
    gel_thickness_m: Range = (2.5e-3, 4.5e-3)


#: The fields of :class:`RigSpread` drawn log-uniformly (ranges spanning a decade or more, or moduli).
LOG_UNIFORM = frozenset({"finger_stiffness_n_per_m", "closing_speed_m_s", "force_noise_n", "width_noise_m",
                         "width_read_hz", "gel_modulus_pa"})

#: The spread ``teleop simulate --randomize-rig`` draws from.
RIG_SPREAD = RigSpread()


@dataclass(frozen=True)
class Rig:
    """One drawn rig: ``known`` (what the lab knows; the record carries it) and ``true`` (the physics)."""

    known: Settings
    true: Settings

    def provenance(self) -> dict[str, Any]:
        """The rig's true values as plain data, for ``Provenance.extra["rig"]``."""
        gripper, sim = self.true.gripper, self.true.simulation
        return {
            "gel_modulus_pa": {s.finger: s.gel_modulus_pa for s in self.true.sensors},
            "gel_thickness_m": {s.finger: s.gel_thickness_m for s in self.true.sensors},
            "camera_hz": {s.finger: s.camera_hz for s in self.true.sensors},
            "finger_stiffness_n_per_m": gripper.finger_stiffness_n_per_m,
            "target_force_n": gripper.target_force_n,
            "closing_speed_m_s": gripper.closing_speed_m_s,
            "width_read_hz": gripper.width_read_hz,
            "load_cell_hz": self.true.load_cell.sample_rate_hz,
            "force_noise_n": sim.force_noise_n,
            "width_noise_m": sim.width_noise_m,
            "width_latency_s": sim.width_latency_s,
            "camera_noise": sim.camera_noise,
            "camera_offset_s": sim.camera_offset_s,
            "illumination_gain": sim.illumination_gain,
        }

    def record(self, record: GraspRecord, *, finger_stiffness_n_per_m: float, target_force_n: float
               ) -> GraspRecord:
        """``record`` (simulated with ``true``) as the lab keeps it: the known sensors and gripper, and
        the true rig in its provenance, with the grasp's own true finger stiffness and target force
        (:class:`~teleop.sim.grasp.GraspTruth`)."""
        rig = {**self.provenance(), "grasp_finger_stiffness_n_per_m": float(finger_stiffness_n_per_m),
               "grasp_target_force_n": float(target_force_n)}
        provenance = dataclasses.replace(record.provenance, extra={**record.provenance.extra, "rig": rig})
        return dataclasses.replace(record, sensors=self.known.sensors, gripper=self.known.gripper,
                                   provenance=provenance)


def _uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(rng.uniform(*bounds))


def _log_uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


def draw(settings: Settings, rng: np.random.Generator, spread: RigSpread = RIG_SPREAD, *,
         vary_gel: bool = False) -> Rig:
    """Draw one rig around ``settings`` (the catalogue gels, the devices' other settings).

    With ``vary_gel`` the gels' datasheet modulus and thickness are drawn too (module notes).
    Pure: the same ``settings`` and ``rng`` state give the same rig; every value comes
    from ``rng`` in a fixed order (the gel's, when drawn, last: the rest of the rig is the
    one drawn without it).
    """
    def pick(name: str) -> float:
        bounds = getattr(spread, name)
        return _log_uniform(rng, bounds) if name in LOG_UNIFORM else _uniform(rng, bounds)

    gripper = dataclasses.replace(
        settings.gripper,
        finger_stiffness_n_per_m=pick("finger_stiffness_n_per_m"),
        target_force_n=pick("target_force_n"),
        closing_speed_m_s=pick("closing_speed_m_s"),
        width_read_hz=pick("width_read_hz"),
    )
    load_cell = dataclasses.replace(settings.load_cell,
                                    sample_rate_hz=float(spread.load_cell_hz[rng.integers(len(spread.load_cell_hz))]))
    sim_values = {name: pick(name) for name in ("force_noise_n", "width_noise_m", "width_latency_s", "camera_noise",
                                                "camera_offset_s", "illumination_gain")}
    simulation = dataclasses.replace(settings.simulation, **sim_values)
    camera_hz = pick("camera_hz")  # both cameras of a rig are alike
    known_sensors = tuple(dataclasses.replace(s, camera_hz=camera_hz) for s in settings.sensors)
    tolerances = [(_uniform(rng, (-spread.gel_modulus_tolerance, spread.gel_modulus_tolerance)),
                   _uniform(rng, (-spread.gel_thickness_tolerance, spread.gel_thickness_tolerance)))
                  for _ in known_sensors]
    if vary_gel:
        gel = {"gel_modulus_pa": pick("gel_modulus_pa"), "gel_thickness_m": pick("gel_thickness_m")}
        known_sensors = tuple(dataclasses.replace(s, **gel) for s in known_sensors)
    true_sensors = tuple(
        dataclasses.replace(s, gel_modulus_pa=s.gel_modulus_pa * (1.0 + modulus),
                            gel_thickness_m=s.gel_thickness_m * (1.0 + thickness))
        for s, (modulus, thickness) in zip(known_sensors, tolerances, strict=True)
    )
    known = dataclasses.replace(settings, sensors=known_sensors, gripper=gripper, load_cell=load_cell,
                                simulation=simulation)
    return Rig(known=known, true=dataclasses.replace(known, sensors=true_sensors))
