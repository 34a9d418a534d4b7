"""Physics and psychophysics constants the packages share, with their sources.

The sensor's resolution limit
-----------------------------
Under the half-space approximation gel and object feel the same pressure, so
with the gel pressed by ``d`` the object's own indentation is
``d * k_object / k_gel`` (``k = (1 - nu^2) / E``). A change of E by the Weber
fraction ``w`` (:data:`WEBER_FRACTION`: the smallest change of compliance a
person feels, about 15 %; Bergmann Tiest and Kappers, IEEE ToH 2009) moves that
indentation by ``w * d * k_object / k_gel``; the sensor sees the change only
while it is at least its depth resolution ``r``, even with the gel pressed by its
whole thickness ``t``. Stiffer objects than

    E_limit = w * (t / r) * (1 - nu_object^2) / k_gel

cannot be told apart by the mechanics (:func:`resolution_limit_pa`, which
:meth:`teleop.settings.SensorSettings.resolution_limit_pa` asks;
6.8 MPa for the shipped 275 kPa, 3 mm gel resolving 20 um): an estimator reports
them as ``lower_bound`` at that limit, and the display renders it as rigid.
"""

from __future__ import annotations

__all__ = ["E_MAX_PA", "E_MIN_PA", "WEBER_FRACTION", "resolution_limit_pa"]

#: Young's modulus of the stiffest solid, diamond's, about 1e12 Pa (1.05e12 Pa: Klein and Cardinale,
#: Diamond and Related Materials 1993): no object labelled or estimated is stiffer.
E_MAX_PA = 1e12
#: Below the softest gels and foams a gripper holds (ultrasoft hydrogels are a few kPa).
E_MIN_PA = 1e3

#: Smallest relative change of an object's compliance a person feels when squeezing it
#: (Bergmann Tiest and Kappers, IEEE Transactions on Haptics 2009: about 15 %).
WEBER_FRACTION = 0.15


def resolution_limit_pa(*, gel_thickness_m: float, depth_resolution_m: float, gel_compliance_per_pa: float,
                        object_poisson: float) -> float:
    """E (Pa) above which a gel cannot tell objects apart (module notes).

    Parameters
    ----------
    gel_thickness_m : float
        The gel's thickness t (m).
    depth_resolution_m : float
        The smallest depth change the sensor resolves, r (m).
    gel_compliance_per_pa : float
        The gel's k = (1 - nu^2) / E (1/Pa).
    object_poisson : float
        The object's Poisson's ratio.
    """
    return WEBER_FRACTION * (gel_thickness_m / depth_resolution_m) * (1.0 - object_poisson**2) / gel_compliance_per_pa
