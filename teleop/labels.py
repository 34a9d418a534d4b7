"""Where an object's label comes from: the one list the bus, the records and the tools share.

``"catalogue"``
    The object's entry in an object catalogue (``configs/objects.toml``, the published table).
``"durometer"``
    A measured Shore hardness, converted to a Young's modulus by a documented model.
``"datasheet"``
    The maker's stated modulus.
``"measured"``
    A modulus measured otherwise (a tensile or indentation test).
"""

from __future__ import annotations

__all__ = ["LABEL_SOURCES"]

LABEL_SOURCES = ("catalogue", "durometer", "datasheet", "measured")
