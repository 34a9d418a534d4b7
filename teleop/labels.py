"""What a grasped object is and what its Young's modulus is: labels, where they come from, and
the Shore hardness model.

Label sources
-------------
:data:`LABEL_SOURCES` is the one list the bus (the ``label`` message), the records and the tools
share:

``"catalogue"``
    The object's entry in an object catalogue (``configs/objects.toml``, the published table).
``"durometer"``
    A measured Shore hardness, converted to a Young's modulus by the model below.
``"datasheet"``
    The maker's stated modulus.
``"measured"``
    A modulus measured otherwise (a tensile or indentation test).

Shore hardness to Young's modulus
---------------------------------
A durometer (ASTM D2240) reads how far a spring-loaded indenter sinks into the object; no
exact relation to E exists (the reading also depends on viscoelasticity, the dwell time and
the object's thickness), so a converted label is good to a factor of about 2 (worse at the
soft end, where Gent's relation overestimates E), and ``detail`` says how it was converted.

Shore A, readings 10 to 90 (:data:`SHORE_A_RANGE`): Gent's relation,

    E = 0.0981 (56 + 7.62336 S) / (0.137505 (254 - 2.54 S))  MPa,

from A. N. Gent, "On the relation between indentation hardness and Young's modulus",
*Rubber Chemistry and Technology* 31 (4), 896-906 (1958) (the form with the ASTM D2240 type A
spring force and indenter, as quoted in the durometer literature). It is the relation the
shipped catalogue's rubbers use (Shore A 40: 1.69 MPa, A 50: 2.46 MPa, A 80: 9.35 MPa). It
gives E -> infinity as S -> 100 and overestimates the softest rubbers; ASTM D2240 counts
readings below 10 and above 90 as unreliable (measure a softer object on the Shore 00 scale,
a harder one on Shore D, which is not converted here).

Shore 00, readings 45 to 90 (:data:`SHORE_00_RANGE`): the durometer makers' comparison table
of the A and 00 scales (:data:`SHORE_A_00_TABLE`; A 5 = 00 45, A 20 = 00 70, A 40 = 00 86,
A 70 = 00 95, as reproduced e.g. in https://www.eng-tips.com/threads/conversion-of-shore-a-to-shore-oo.50796/;
a typical shoe heel reads 70 A and 95 00), interpolated linearly to a Shore A value, then
Gent's relation. Below 00 45 the table has no A equivalent (gels, foams, the softest
silicones): label such objects with the maker's modulus (``datasheet``) or a measured one.
Above 00 90 readings are unreliable: measure on the A scale.

Readings outside a range raise :class:`LabelError` naming the range and what to do instead.

Labels
------
:class:`ObjectLabel` is one label (object name, modulus or None, source, detail), the body of a
``label`` bus message without its grasp id. :func:`catalogue_label`, :func:`shore_label` and
:func:`modulus_label` build one; :func:`label_from_fields` from a CSV row's fields (``teleop
label``), :func:`parse_label` from what an operator types in the console::

    stress_ball                  the catalogue's entry
    blue gel pad shore 00 60     a Shore 00 reading (also "shore A 40", "A40", "00-60")
    cork mat 12 MPa              the maker's modulus (Pa, kPa, MPa or GPa)
    cork mat 12 MPa measured     a modulus measured otherwise
"""

from __future__ import annotations

import bisect
import difflib
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from teleop.errors import TeleopError
from teleop.physics import E_MAX_PA
from teleop.units import format_pa

if TYPE_CHECKING:  # at run time the bus's messages import this module
    from teleop.bus.messages import LabelBody

__all__ = [
    "LABEL_SOURCES",
    "MAX_OBJECT_NAME_CHARS",
    "SHORE_00_RANGE",
    "SHORE_A_00_TABLE",
    "SHORE_A_RANGE",
    "SHORE_SCALES",
    "LabelError",
    "ObjectLabel",
    "catalogue_label",
    "describe_label",
    "gent_modulus_pa",
    "label_from_fields",
    "modulus_label",
    "parse_label",
    "shore_00_to_a",
    "shore_label",
    "shore_to_modulus_pa",
]

LABEL_SOURCES = ("catalogue", "durometer", "datasheet", "measured")

MAX_OBJECT_NAME_CHARS = 128  # the label message's object_name (teleop.bus.wire)

SHORE_SCALES = ("A", "00")
SHORE_A_RANGE = (10.0, 90.0)
#: A stated modulus (Pa): no solid is stiffer than diamond (:data:`~teleop.physics.E_MAX_PA`); the softest
#: a gripper holds are gels of a few kPa, so 1 Pa is a generous floor.
LABEL_RANGE_PA = (1.0, E_MAX_PA)
SHORE_00_RANGE = (45.0, 90.0)

#: (Shore A, Shore 00) pairs of the makers' comparison table, A ascending (module notes).
SHORE_A_00_TABLE = (
    (5.0, 45.0), (10.0, 55.0), (15.0, 62.0), (20.0, 70.0), (25.0, 76.0), (30.0, 80.0),
    (35.0, 83.0), (40.0, 86.0), (45.0, 88.0), (50.0, 90.0), (55.0, 91.0), (60.0, 93.0),
    (65.0, 94.0), (70.0, 95.0), (75.0, 97.0), (80.0, 98.0),
)  # fmt: skip

_UNITS = {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "gpa": 1e9}


class LabelError(TeleopError, ValueError):
    """A label cannot be made: an unknown object without a modulus, a reading out of range, a bad number."""


# --------------------------------------------------------------------------- the Shore model


def _reading(value: Any, scale: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise LabelError(f"Shore {scale} {value!r} is not a number") from None
    if not math.isfinite(number):
        raise LabelError(f"Shore {scale} {value!r} is not a finite number")
    return number


def _in_range(value: Any, scale: str, bounds: tuple[float, float], covered: str, *, below: str,
              above: str) -> float:
    """The Shore reading on ``scale`` as a number within ``bounds``; LabelError with advice otherwise."""
    s = _reading(value, scale)
    low, high = bounds
    if not low <= s <= high:
        raise LabelError(f"Shore {scale} {s:g} is outside {low:g} to {high:g}, {covered}: "
                         f"{below if s < low else above}")
    return s


def gent_modulus_pa(shore_a: float) -> float:
    """Young's modulus (Pa) of a Shore A reading by Gent's relation (module notes).

    Raises
    ------
    LabelError
        The reading is not a number in :data:`SHORE_A_RANGE`.
    """
    s = _in_range(shore_a, "A", SHORE_A_RANGE, "the readings Gent's relation and ASTM D2240 cover",
                  below="measure it on the Shore 00 scale, or give the maker's modulus",
                  above="measure it on the Shore D scale or give the maker's modulus")
    return _gent(s)


def _gent(shore_a: float) -> float:
    return 0.0981 * (56.0 + 7.62336 * shore_a) / (0.137505 * (254.0 - 2.54 * shore_a)) * 1e6


def shore_00_to_a(shore_00: float) -> float:
    """The Shore A value of a Shore 00 reading, by the makers' comparison table (module notes).

    Raises
    ------
    LabelError
        The reading is not a number in :data:`SHORE_00_RANGE`.
    """
    s = _in_range(shore_00, "00", SHORE_00_RANGE, "the readings the conversion covers",
                  below="the table has no Shore A equivalent this soft: give the maker's modulus (datasheet) "
                        "or a measured one",
                  above="readings this hard are unreliable on the 00 scale: measure it on the Shore A scale")
    oo_values = [oo for _, oo in SHORE_A_00_TABLE]
    i = min(max(bisect.bisect_left(oo_values, s), 1), len(oo_values) - 1)
    (a0, o0), (a1, o1) = SHORE_A_00_TABLE[i - 1], SHORE_A_00_TABLE[i]
    return a0 + (a1 - a0) * (s - o0) / (o1 - o0)


def shore_to_modulus_pa(value: float, scale: str) -> float:
    """Young's modulus (Pa) of a Shore reading on ``scale`` ("A" or "00"; "OO" also reads as 00).

    Shore A readings below 10 are refused even when reached from a Shore 00 reading: the
    00 path converts to A first (module notes) and then uses Gent's relation from A 5 up,
    the table's softest entry.

    Raises
    ------
    LabelError
        Unknown scale, or a reading outside its range.
    """
    name = _scale(scale)
    if name == "A":
        return gent_modulus_pa(value)
    # The table's low end (A 5 to 10) lies below the A readings accepted; the conversion covers it.
    return _gent(shore_00_to_a(value))


def _scale(scale: str) -> str:
    text = str(scale).strip().upper().replace("O", "0")
    if text not in SHORE_SCALES:
        raise LabelError(f"Shore scale {scale!r}: expected A or 00")
    return text


# --------------------------------------------------------------------------- labels


@dataclass(frozen=True)
class ObjectLabel:
    """One label: what the object is and its modulus, with where that comes from.

    Parameters
    ----------
    object_name : str
        The object (a catalogue name, or the lab's own name for it), 1 to 128 characters.
    modulus_pa : float or None
        Young's modulus, Pa, finite and > 0; None: the catalogue's entry for ``object_name``.
    source : str
        One of :data:`LABEL_SOURCES`.
    detail : str
        Where the value comes from in words (the catalogue and its entry, the Shore reading and
        the conversion, the datasheet).
    """

    object_name: str
    modulus_pa: float | None
    source: str
    detail: str = ""

    def __post_init__(self) -> None:
        name = self.object_name
        if not isinstance(name, str) or not name.strip() or len(name) > MAX_OBJECT_NAME_CHARS:
            raise LabelError(f"object name {name!r}: expected 1 to {MAX_OBJECT_NAME_CHARS} characters")
        if self.source not in LABEL_SOURCES:
            raise LabelError(f"label source {self.source!r}: expected one of {', '.join(LABEL_SOURCES)}")
        m = self.modulus_pa
        if m is not None and not (isinstance(m, int | float) and math.isfinite(m) and m > 0):
            raise LabelError(f"modulus {m!r} Pa for {name!r}: expected a finite number > 0")

    def body(self, grasp_id: str) -> dict[str, Any]:
        """The ``label`` bus message's body for grasp ``grasp_id``."""
        return {
            "grasp_id": grasp_id,
            "object_name": self.object_name,
            "modulus_pa": None if self.modulus_pa is None else float(self.modulus_pa),
            "source": self.source,
            "detail": self.detail,
        }


def describe_label(label: ObjectLabel | LabelBody) -> str:
    """A label (as given, or the body of a ``label`` message) in one line for people:
    ``stress_ball  E 40 kPa  (catalogue)``."""
    modulus = label.modulus_pa
    value = "E from the catalogue" if modulus is None else f"E {format_pa(modulus)}"
    return f"{label.object_name}  {value}  ({label.source})"


def _by_name(catalogue: Iterable[Any]) -> dict[str, Any]:
    return {spec.name: spec for spec in catalogue}


def _unknown(name: str, names: Sequence[str], where: str) -> LabelError:
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.6)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    return LabelError(
        f"object {name!r} is not in {where}{hint}: give its modulus (modulus_pa, with source "
        "datasheet or measured) or a Shore hardness (shore_a or shore_00)"
    )


def catalogue_label(name: str, catalogue: Iterable[Any], *, where: str = "the catalogue") -> ObjectLabel:
    """The label of catalogue object ``name`` (source ``catalogue``, its modulus written out).

    ``catalogue``: :class:`~teleop.catalogue.ObjectSpec` entries; ``where`` names it in errors
    and in the label's detail.

    Raises
    ------
    LabelError
        ``name`` is not in the catalogue (with the closest names).
    """
    objects = _by_name(catalogue)
    spec = objects.get(name)
    if spec is None:
        raise _unknown(name, list(objects), where)
    detail = f"{where}: {spec.material}, E {spec.modulus_pa:.6g} Pa" + (f"; {spec.source}" if spec.source else "")
    return ObjectLabel(name, float(spec.modulus_pa), "catalogue", detail[:1024])


def shore_label(name: str, value: float, scale: str) -> ObjectLabel:
    """The label of ``name`` from a Shore reading (source ``durometer``; the detail names the model).

    Raises
    ------
    LabelError
        Unknown scale or a reading out of range.
    """
    scale = _scale(scale)
    reading = _reading(value, scale)
    modulus = shore_to_modulus_pa(reading, scale)
    if scale == "A":
        how = "by Gent's relation (Gent 1958)"
    else:
        how = f"= Shore A {shore_00_to_a(reading):.3g} by the makers' A/00 table, then Gent's relation (Gent 1958)"
    return ObjectLabel(name, modulus, "durometer", f"Shore {scale} {reading:g} {how}: E {modulus:.4g} Pa")


def modulus_label(name: str, modulus_pa: float, source: str = "datasheet", detail: str = "") -> ObjectLabel:
    """The label of ``name`` with a stated modulus (source ``datasheet`` or ``measured``).

    Raises
    ------
    LabelError
        The modulus is not a finite number > 0, or ``source`` is neither.
    """
    if source not in ("datasheet", "measured"):
        raise LabelError(f"a stated modulus has source datasheet or measured, not {source!r}")
    value = _number(modulus_pa, "modulus_pa")
    if not value > 0:
        raise LabelError(f"modulus_pa {modulus_pa!r}: expected a number > 0 (Pa)")
    if not LABEL_RANGE_PA[0] <= value <= LABEL_RANGE_PA[1]:  # a typo'd exponent would train the model on it
        raise LabelError(f"modulus_pa {modulus_pa!r}: expected {LABEL_RANGE_PA[0]:g} to {LABEL_RANGE_PA[1]:g} Pa "
                         "(diamond's modulus at most): a unit slip?")
    return ObjectLabel(name, value, source, detail or f"{source}: E {value:.6g} Pa")


def _number(text: Any, what: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise LabelError(f"{what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise LabelError(f"{what} {text!r} is not a finite number")
    return value


def label_from_fields(
    object_name: str,
    *,
    catalogue: Iterable[Any] = (),
    modulus_pa: str | float | None = None,
    shore_a: str | float | None = None,
    shore_00: str | float | None = None,
    source: str | None = None,
    detail: str = "",
    where: str = "the catalogue",
) -> ObjectLabel:
    """A label from the fields of one CSV row (``teleop label``); empty strings count as absent.

    At most one of ``modulus_pa``, ``shore_a`` and ``shore_00``. Without ``source``: ``durometer``
    with a Shore reading, ``datasheet`` with a modulus, else ``catalogue`` (the object must be in
    ``catalogue``). A given ``source`` must fit: ``durometer`` needs a Shore reading, ``datasheet``
    and ``measured`` a modulus, ``catalogue`` neither. ``detail`` replaces the generated one.

    Raises
    ------
    LabelError
        Conflicting or bad fields, or an unknown object without a modulus.
    """
    name = (object_name or "").strip()
    if not name:
        raise LabelError("the object is empty: name the object grasped")
    given = {
        key: value
        for key, value in (("modulus_pa", modulus_pa), ("shore_a", shore_a), ("shore_00", shore_00))
        if value is not None and str(value).strip() != ""
    }
    if len(given) > 1:
        raise LabelError(f"{' and '.join(given)} are both given: give one of modulus_pa, shore_a, shore_00")
    source = (source or "").strip() or None
    if source is not None and source not in LABEL_SOURCES:
        raise LabelError(f"source {source!r}: expected one of {', '.join(LABEL_SOURCES)}")
    detail = (detail or "").strip()
    if "shore_a" in given or "shore_00" in given:
        if source not in (None, "durometer"):
            raise LabelError(f"a Shore hardness is a durometer reading: source {source!r} does not fit")
        key = next(iter(given))
        label = shore_label(name, given[key], "A" if key == "shore_a" else "00")
    elif "modulus_pa" in given:
        if source in ("catalogue", "durometer"):
            raise LabelError(
                f"source {source} takes its modulus from "
                + ("the catalogue" if source == "catalogue" else "a Shore reading")
                + ": leave modulus_pa empty, or say datasheet or measured"
            )
        label = modulus_label(name, _number(given["modulus_pa"], "modulus_pa"), source or "datasheet")
    else:
        if source not in (None, "catalogue"):
            raise LabelError(
                f"source {source} needs "
                + ("a Shore hardness (shore_a or shore_00)" if source == "durometer" else "a modulus (modulus_pa)")
            )
        label = catalogue_label(name, catalogue, where=where)
    if detail:
        label = ObjectLabel(label.object_name, label.modulus_pa, label.source, detail[:1024])
    return label


_SHORE = re.compile(
    r"^(?P<name>.+?)\s+(?:shore\s*)?(?P<scale>a|00|oo)\s*[-:=]?\s*(?P<value>[0-9]+(?:\.[0-9]*)?)$",
    re.IGNORECASE,
)
_MODULUS = re.compile(
    r"^(?P<name>.+?)\s+(?:e\s*=?\s*)?(?P<value>[0-9]+(?:\.[0-9]*)?(?:e[-+]?[0-9]+)?)\s*(?P<unit>[kmg]?pa)"
    r"(?:\s+(?P<source>datasheet|measured))?$",
    re.IGNORECASE,
)


def parse_label(text: str, catalogue: Iterable[Any] = (), *, where: str = "the catalogue") -> ObjectLabel:
    """A label from what an operator typed (module notes for the forms).

    Raises
    ------
    LabelError
        Nothing typed, an object not in ``catalogue`` without a hardness or modulus, a reading
        out of range.
    """
    text = " ".join((text or "").split())
    if not text:
        raise LabelError("type the object's name (from the catalogue), or NAME shore A 40, or NAME 120 kPa")
    catalogue = list(catalogue)
    names = _by_name(catalogue)
    if text in names:
        return catalogue_label(text, catalogue, where=where)
    match = _SHORE.match(text)
    if match:
        return shore_label(match["name"].strip(), float(match["value"]), match["scale"])
    match = _MODULUS.match(text)
    if match:
        value = float(match["value"]) * _UNITS[match["unit"].lower()]
        return modulus_label(match["name"].strip(), value, (match["source"] or "datasheet").lower())
    lowered = {name.lower(): name for name in names}
    if text.lower() in lowered:
        return catalogue_label(lowered[text.lower()], catalogue, where=where)
    close = difflib.get_close_matches(text, list(names), n=3, cutoff=0.6)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise LabelError(
        f"{text!r} is not in {where}{hint}: add its hardness (NAME shore A 40, NAME shore 00 60) "
        "or its modulus (NAME 120 kPa)"
    )
