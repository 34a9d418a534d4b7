"""Moduli for people: one formatter for every screen and line that shows one with an SI prefix."""

from __future__ import annotations

import math

__all__ = ["format_pa"]

#: The SI prefixes a modulus is shown with, largest first (below the last: plain Pa).
_PREFIXES = ((1e12, "TPa"), (1e9, "GPa"), (1e6, "MPa"), (1e3, "kPa"))


def format_pa(value_pa: float | None) -> str:
    """A modulus in Pa to three significant figures with an SI prefix: ``3.6 MPa``, ``9 kPa``,
    ``200 GPa``, ``1 TPa``; ``-`` for None or a value that is not finite.

    The value is rounded before the prefix is chosen, so that 999.7 Pa reads ``1 kPa``
    (not ``1e+03 Pa``) and 9.9996e8 Pa reads ``1 GPa``.
    """
    if value_pa is None or not math.isfinite(value_pa):
        return "-"
    rounded = float(f"{value_pa:.3g}")
    for scale, unit in _PREFIXES:
        if abs(rounded) >= scale:
            # rounded has 3 significant figures: "g" shows them without the division's float noise
            return f"{rounded / scale:g} {unit}"
    return f"{rounded:g} Pa"
