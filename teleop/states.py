"""The states of a Young's modulus estimate: the one list the estimator, the bus and the display share.

``"ok"``
    A modulus with a finite interval around it.
``"lower_bound"``
    The object is at least this stiff (e.g. at the sensor's resolution limit).
``"upper_bound"``
    The object is at most this stiff.
``"insufficient_data"``
    A refusal: no modulus, a reason.

The estimator builds them (:class:`estimator.estimate.Estimate`, which states each one's
invariants), the bus carries them (``estimate`` messages, :mod:`teleop.bus.wire`) and the
display renders them (:class:`haptics.mapping.EstimateUpdate`). The order is part of the
learned models' inputs (a one-hot per state), so a new state goes at the end.
"""

from __future__ import annotations

__all__ = ["ESTIMATE_STATES"]

ESTIMATE_STATES = ("ok", "lower_bound", "upper_bound", "insufficient_data")
