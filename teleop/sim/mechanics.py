"""Randomized contact mechanics: what the simulator assumes of the gel and the object, drawn per grasp.

An estimator trained on one simulator learns its contact mechanics: the gel as an
elastic layer bonded to a rigid backing (:mod:`teleop.sim.contact`), the object as a
linear half-space with a bulk term and a densification law
(:func:`teleop.sim.grasp.load_curve`). ``teleop simulate --vary-contact`` draws those
assumptions for every grasp from :class:`ContactSpread` (one documented place for
the distribution) with :func:`draw_mechanics`; :class:`ContactMechanics` applies them.

The held-out model
------------------
The gel as an elastic half-space (``--gel-model half-space``) is the contact model
kept for testing an estimator beyond its training mechanics: no draw here is a
half-space. Every drawn gel is a layer (bonded, sliding on its backing or between,
of an effective thickness), which the half-space is not for any contact wider than
the gel is thick; ``--vary-contact`` with ``--gel-model half-space`` is refused.

What the estimator sees
-----------------------
Nothing of a draw: the record keeps the frames, forces, widths, timestamps and the
rig the lab knows; the drawn values go to ``provenance.extra["mechanics"]``
(:meth:`ContactMechanics.provenance`, with the size the grasp used) for analysis only.
The label stays the catalogue's Young's modulus.

Ranges (:data:`CONTACT_SPREAD`)
-------------------------------
=========================  ===========================  ============================================
quantity                   range                        why
=========================  ===========================  ============================================
gel backing slip           0-1, uniform                 0: the gel bonded to its acrylic (as built);
                                                        1: on a lubricated backing (Chen & Engel's
                                                        frictionless base); between: a partly bonded
                                                        gel (a blend of the two compliances)
gel effective thickness    x [0.6, 1.5], log-uniform    the thin-layer correction scaled: a gel not
                                                        uniform (domed, cast unevenly, worn), a
                                                        stiff skin or paint coat; Shull, Mater. Sci.
                                                        Eng. R 36 (2002) 1 for how strongly it matters
object Poisson's ratio     0.3-0.5, uniform,            metals, glass, plastics and open-cell foams
                           instead of the catalogue's   (Gibson & Ashby) near 0.3, rubbers and gels
                                                        0.5; the published object table gives none
                                                        (the catalogue's 0.4 stands in for all, as
                                                        the estimator's ``sensing.object_poisson``)
densification strain      material's x [0.75, 1.15],   Gibson & Ashby, Cellular Solids (1997):
                           uniform                      eps_D = 1 - 1.4 rho*/rho_s, 0.6-0.92 for
                                                        foams of relative density 0.06-0.29
densification sharpness    0.6-3, log-uniform           how abruptly it sets in: 1 the simulator's
                                                        law, 3 a wall (a foam's plateau, then
                                                        solid), 0.6 gradual (food, closed cells)
rubber stiffening weight   0-1, uniform                 0 Hookean (the simulator's), 1 a Gent solid
Gent locking J_m           1-100, log-uniform           Gent, Rubber Chem. Technol. 69 (1996) 59:
                                                        30-100 for rubbers; near 1 for soft tissue
                                                        (Horgan & Saccomandi, Biomech. Model.
                                                        Mechanobiol. 1 (2003) 251)
friction stiffening        0-5 %, uniform               the contact with friction, approximated
                                                        (below)
object size                x [0.8, 1.2] per body        objects of a class differ from the
                           axis, uniform                catalogue's one; tied axes alike, kept
                                                        graspable (``shapes.scaled_size``)
=========================  ===========================  ============================================

How each applies
----------------
The gel (:meth:`ContactMechanics.gel_body`) is the sensor's, its modulus and Poisson's
ratio as the (true) rig has them, its thickness in the solver scaled, and its backing
slip set: the contact solver's layer kernel (:class:`~teleop.sim.contact.Body`). The
gel's Poisson's ratio is its own, never drawn: the solver tabulates one layer
correction per Poisson's ratio, and the slip one once.

The object's non-linear laws map its linear displacement X (both contacts plus bulk,
at each force of the ladder) as the simulator's densification law does, rubber first
(the material), then densification (the body's limit); both keep the small-force
response (slope 1 at X = 0) and stiffen it beyond:

* rubber (:func:`rubber_stiffen`): the force that moves a Hookean object by X puts it
  under the nominal stress E X / L (L its extent); a rubber-like one under that stress
  sits at the strain eps where (1 - w) eps + w g(eps) = X / L and moves eps L, g the
  uniaxial compression of an incompressible Gent solid,
  (1/3) (lambda^-2 - lambda) J_m / (J_m - (I1 - 3)), lambda = 1 - eps. w blends Hookean
  and Gent (compressible solids stiffen less than the incompressible rubber).
* densification (:func:`densify`): X_max (1 - exp(-(X / X_max)^n))^(1/n), X_max the
  densification strain times L; n = 1 is the simulator's law.

Friction: the solver's contact is frictionless. Friction between dissimilar bodies
restrains the mismatch of their surfaces' radial displacements and stiffens a Hertzian
contact by a few per cent at most (Johnson, Contact Mechanics, ch. 5; Goodman, J. Appl.
Mech. 29 (1962) 515; Spence, J. Elasticity 5 (1975) 297). It is approximated by the
object's local (contact) modulus times (1 + the drawn stiffening), whatever the pair of
materials; the bulk term keeps the catalogue's modulus.

Cost: no solve is added. The object's Poisson's ratio and modulus only scale the
object's half of the solver's kernels; the effective thickness gives each grasp its own
layer kernels (about 10 ms, as a randomized rig's gel thickness already does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from teleop.catalogue import ObjectSpec
from teleop.settings import SensorSettings
from teleop.sim.contact import Body
from teleop.sim.shapes import scaled_size

__all__ = [
    "CONTACT_SPREAD",
    "ContactMechanics",
    "ContactSpread",
    "LOG_UNIFORM",
    "densify",
    "draw_mechanics",
    "gent_stress",
    "rubber_stiffen",
]

Range = tuple[float, float]

# Bisection steps of the rubber law's inverse, on the fraction of the linear strain: 2^-60 of it.
_BISECTIONS = 60


@dataclass(frozen=True)
class ContactSpread:
    """How contact mechanics differ: every range one is drawn from (see the module notes for why).

    Uniform unless :data:`LOG_UNIFORM` names the field; ``size_factor`` is drawn once per
    body axis.
    """

    base_slip: Range = (0.0, 1.0)
    thickness_factor: Range = (0.6, 1.5)
    object_poisson: Range = (0.3, 0.5)
    densification_factor: Range = (0.75, 1.15)
    densification_sharpness: Range = (0.6, 3.0)
    rubber_weight: Range = (0.0, 1.0)
    gent_locking: Range = (1.0, 100.0)
    friction_stiffening: Range = (0.0, 0.05)
    size_factor: Range = (0.8, 1.2)


#: The fields of :class:`ContactSpread` drawn log-uniformly (ratios and spans of a decade or more).
LOG_UNIFORM = frozenset({"thickness_factor", "densification_sharpness", "gent_locking"})

#: The spread ``teleop simulate --vary-contact`` draws from.
CONTACT_SPREAD = ContactSpread()


def densify(linear_m: np.ndarray, limit_m: float, *, sharpness: float) -> np.ndarray:
    """X_max (1 - exp(-(X / X_max)^n))^(1/n): displacement X (m, >= 0) bounded by ``limit_m`` = X_max.

    ``sharpness`` n > 0; n = 1 is the grasp simulator's densification law.
    """
    ratio = np.asarray(linear_m, dtype=np.float64) / limit_m
    return limit_m * (-np.expm1(-(ratio**sharpness))) ** (1.0 / sharpness)


def gent_stress(strain: np.ndarray, *, locking: float) -> np.ndarray:
    """Nominal compressive stress over E of an incompressible Gent solid in uniaxial compression.

    (1/3) (lambda^-2 - lambda) J_m / (J_m - (I1 - 3)) at the nominal strain eps = 1 - lambda,
    written in eps so that small strains lose no digits; inf where the chains lock
    (I1 - 3 >= J_m) or eps >= 1. Slope 1 at eps = 0; J_m -> inf is neo-Hookean.
    """
    eps = np.asarray(strain, dtype=np.float64)
    stretch = 1.0 - eps
    valid = stretch > 0
    safe = np.where(valid, stretch, 1.0)
    excess = eps * eps * (3.0 - eps) / safe  # I1 - 3 = lambda^2 + 2 / lambda - 3
    neo_hookean = eps * (3.0 - 3.0 * eps + eps * eps) / (3.0 * safe * safe)
    valid &= excess < locking
    return np.where(valid, neo_hookean * locking / np.where(valid, locking - excess, 1.0), np.inf)


def rubber_stiffen(linear_m: np.ndarray, *, extent_m: float, weight: float, locking: float) -> np.ndarray:
    """The displacement (m) of a strain-stiffening object where a Hookean one moves ``linear_m`` (>= 0).

    The Hookean strain X / L (L = ``extent_m``) is the stress over E; the returned X' solves
    (1 - w) eps + w g(eps) = X / L with eps = X' / L, g = :func:`gent_stress`. X' <= X.
    """
    target = np.asarray(linear_m, dtype=np.float64) / extent_m
    lo, hi = np.zeros_like(target), np.ones_like(target)  # fractions of the Hookean strain
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        eps = mid * target
        # A Hookean object (weight 0) skips g: 0 times its infinite stress past locking is NaN.
        stiffened = weight * gent_stress(eps, locking=locking) if weight else 0.0
        above = (1.0 - weight) * eps + stiffened > target
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return 0.5 * (lo + hi) * target * extent_m


@dataclass(frozen=True)
class ContactMechanics:
    """One drawn set of contact mechanics (fields as in :class:`ContactSpread`)."""

    base_slip: float
    thickness_factor: float
    object_poisson: float
    densification_factor: float
    densification_sharpness: float
    rubber_weight: float
    gent_locking: float
    friction_stiffening: float
    size_factors: tuple[float, float, float]

    def gel_body(self, sensor: SensorSettings) -> Body:
        """The sensor's gel as the contact solver takes it: a layer of the effective thickness."""
        return Body(sensor.gel_modulus_pa, sensor.gel_poisson, sensor.gel_thickness_m * self.thickness_factor,
                    base_slip=self.base_slip)

    def object_body(self, obj: ObjectSpec) -> Body:
        """The object's local response: the drawn Poisson's ratio, the modulus stiffened by friction."""
        return Body(obj.modulus_pa * (1.0 + self.friction_stiffening), self.object_poisson)

    def object_size(self, obj: ObjectSpec, size: tuple[float, float, float], *,
                    max_width_m: float) -> tuple[float, float, float]:
        """The object's extents (m) for this grasp (:func:`~teleop.sim.shapes.scaled_size`)."""
        return scaled_size(obj, size, self.size_factors, max_width_m=max_width_m)

    def object_response(self, linear_m: np.ndarray, *, extent_m: float, densification_strain: float
                        ) -> np.ndarray:
        """The object's displacement (m) where a linear one moves ``linear_m`` (module notes).

        ``densification_strain`` is the material's, as the grasp simulator has it; the drawn
        factor scales it. Odd in X: a stiff object's displacement can come out a hair below
        zero within the contact solver's tolerance, and keeps its sign and size.
        """
        linear = np.asarray(linear_m, dtype=np.float64)
        rubber = rubber_stiffen(np.abs(linear), extent_m=extent_m, weight=self.rubber_weight,
                                locking=self.gent_locking)
        return np.sign(linear) * densify(rubber, densification_strain * self.densification_factor * extent_m,
                                         sharpness=self.densification_sharpness)

    def provenance(self) -> dict[str, Any]:
        """The drawn values as plain data, for ``Provenance.extra["mechanics"]``."""
        return {
            "base_slip": self.base_slip,
            "thickness_factor": self.thickness_factor,
            "object_poisson": self.object_poisson,
            "densification_factor": self.densification_factor,
            "densification_sharpness": self.densification_sharpness,
            "rubber_weight": self.rubber_weight,
            "gent_locking": self.gent_locking,
            "friction_stiffening": self.friction_stiffening,
            "size_factors": list(self.size_factors),
        }


def draw_mechanics(rng: np.random.Generator, spread: ContactSpread = CONTACT_SPREAD) -> ContactMechanics:
    """Draw one set of contact mechanics from ``spread``.

    Pure: the same ``rng`` state gives the same mechanics; every value comes from ``rng``
    in the order of the fields, the three size factors last.
    """
    def pick(name: str) -> float:
        lo, hi = getattr(spread, name)
        if name in LOG_UNIFORM:
            return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        return float(rng.uniform(lo, hi))

    drawn = {name: pick(name) for name in ("base_slip", "thickness_factor", "object_poisson", "densification_factor",
                                           "densification_sharpness", "rubber_weight", "gent_locking",
                                           "friction_stiffening")}
    size_factors = tuple(float(f) for f in rng.uniform(*spread.size_factor, size=3))
    return ContactMechanics(**drawn, size_factors=size_factors)
