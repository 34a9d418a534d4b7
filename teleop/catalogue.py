"""Object catalogues: what the robot may grasp, with the ground-truth modulus.

Two formats are read:

* the project's own TOML catalogue (``configs/objects.toml``): one
  ``[[objects]]`` table per object with ``name``, ``shape``, ``material``,
  ``modulus_pa``, optional ``poisson``, ``size_m`` (x, y, z extents, m) and
  ``texture_m`` (surface roughness amplitude, m), ``source``;
* the published object table (CSV, label column ``Modulus [Pa]``, shape and
  material columns, optional ``Radius [m]``), as in
  ``../shared/seed/dataset_objects_and_compliance.csv``.

Shapes are normalised to ``sphere``, ``cylinder``, ``box``, ``hex_prism`` and
``irregular``; materials are stripped and lower-cased. A TOML catalogue's material must be one of
:data:`MATERIALS` (the simulator's tables look materials up and fall back to defaults, so a typo
would silently change the physics); the published table's materials are kept as they are (a table
the project does not own: every one it holds today is in :data:`MATERIALS`). A TOML catalogue holds
``[[objects]]`` tables and nothing else: a misspelt ``[[object]]`` would drop objects silently.

Sizes: the table's ``Radius [m]`` gives a sphere's or cylinder's diameter and nothing else, so a
cylinder from the table is taken as long as it is wide (size ``(d, d, d)``); give its length in a
TOML catalogue's ``size_m`` where it matters. The simulator takes a cylinder as round and a hex
prism as regular: their cross-section is ``size_m[0]`` (the diameter, or the width across flats),
so a TOML ``size_m[1]`` that says otherwise (a cylinder's not equal to its diameter, a hex prism's
across corners not ``size_m[0] / cos 30``, within :data:`SECTION_TOLERANCE`) is refused rather
than ignored; so is a sphere whose three extents are not equal (the simulator reads ``size_m[0]``).
"""

from __future__ import annotations

import csv
import math
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

from teleop.bus.messages import SCHEMAS
from teleop.errors import SettingsError
from teleop.physics import E_MAX_PA
from teleop.settings import config_dir

__all__ = [
    "MATERIALS",
    "MAX_NAME_CHARS",
    "MODULUS_RANGE_PA",
    "SHAPES",
    "ObjectSpec",
    "default_catalogue_path",
    "load_catalogue",
    "read_object_table",
    "read_toml_catalogue",
]

SHAPES = ("sphere", "cylinder", "box", "hex_prism", "irregular")
#: The material classes a TOML catalogue may name: those of configs/objects.toml, of the published
#: object table (which adds ceramic and paper) and of the simulator's per-material tables
#: (teleop.sim.shapes.TEXTURE_BY_MATERIAL_M, teleop.sim.grasp.DENSIFICATION_STRAIN).
MATERIALS = ("rubber", "foam", "plastic", "wood", "metal", "glass", "food", "ceramic", "paper")
#: A plausible Young's modulus, Pa. No solid is stiffer than diamond (E_MAX_PA, about 1e12 Pa); the
#: softest objects a gripper holds are gels of a few kPa, so 1 Pa is a generous floor. Below it the
#: simulator's scripted squeeze has no finite length (an exponent typo such as 1e-20 would crash it).
MODULUS_RANGE_PA = (1.0, E_MAX_PA)
#: The relative slack of a TOML cylinder's or hex prism's ``size_m[1]`` against the one its
#: ``size_m[0]`` implies (module notes): enough for extents rounded to 0.1 mm.
SECTION_TOLERANCE = 0.02

# An object's name travels in bus messages (grasp_event, label) whose schemas cap its length; a
# catalogue name over the smallest cap would pass here and be refused mid-run (or by `teleop label`).
MAX_NAME_CHARS = min(SCHEMAS[kind].fields["object_name"].max_chars for kind in ("grasp_event", "label"))
_SHAPE_ALIASES = {
    "sphere": "sphere",
    "cylinder": "cylinder",
    "box": "box",
    "rectangular": "box",
    "hex": "hex_prism",
    "hex_prism": "hex_prism",
    "hexagonal prism": "hex_prism",
    "irregular": "irregular",
}


def default_catalogue_path() -> Path:
    return config_dir() / "objects.toml"


@dataclass(frozen=True)
class ObjectSpec:
    """One graspable object.

    Parameters
    ----------
    name : str
        1 to :data:`MAX_NAME_CHARS` characters, no leading or trailing whitespace.
    shape : str
        One of :data:`SHAPES`.
    material : str
        Lower-case material class: one of :data:`MATERIALS` from a TOML catalogue; the published
        table's as it has it.
    modulus_pa : float
        Young's modulus, Pa, within :data:`MODULUS_RANGE_PA`.
    poisson : float
        Poisson's ratio in [0, 0.5].
    size_m : (float, float, float) or None
        Extents along x (between the fingers), y and z, metres. Sphere: all equal
        to the diameter; cylinder: (diameter, diameter, length); box: edges;
        hex_prism: (across flats, across corners, length). None: unknown (the
        simulator draws a plausible size).
    texture_m : float
        Surface roughness amplitude, metres.
    """

    name: str
    shape: str
    material: str
    modulus_pa: float
    poisson: float = 0.4
    size_m: tuple[float, float, float] | None = None
    texture_m: float = 0.0
    source: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError(f"object name is empty: expected 1 to {MAX_NAME_CHARS} characters")
        if self.name != self.name.strip():
            # The CSV table strips its cells; a padded TOML name would be a different object there.
            raise ValueError(f"object {self.name!r}: the name starts or ends with whitespace; remove it")
        if len(self.name) > MAX_NAME_CHARS:
            raise ValueError(f"object {_short(self.name)}: the name has {len(self.name)} characters, at most "
                             f"{MAX_NAME_CHARS} (the bus's label message carries no more)")
        if self.shape not in SHAPES:
            raise ValueError(f"object {self.name!r}: shape {self.shape!r} is not one of {SHAPES}")
        if not (math.isfinite(self.modulus_pa) and self.modulus_pa > 0):
            raise ValueError(f"object {self.name!r}: modulus_pa must be finite and > 0, got {self.modulus_pa}")
        low, high = MODULUS_RANGE_PA
        if not low <= self.modulus_pa <= high:
            raise ValueError(f"object {self.name!r}: modulus_pa {self.modulus_pa:g} is outside the plausible "
                             f"range {low:g} to {high:g} Pa (1 Pa: softer than any gel; {high:g} Pa: diamond)")
        if not 0.0 <= self.poisson <= 0.5:
            raise ValueError(f"object {self.name!r}: poisson must be in [0, 0.5], got {self.poisson}")
        if self.size_m is not None and (
            len(self.size_m) != 3 or not all(math.isfinite(s) and 0 < s < 1.0 for s in self.size_m)
        ):
            raise ValueError(f"object {self.name!r}: size_m must be three extents in (0, 1) m, got {self.size_m}")
        if not (math.isfinite(self.texture_m) and 0 <= self.texture_m < 1e-3):
            raise ValueError(f"object {self.name!r}: texture_m must be in [0, 1e-3) m, got {self.texture_m}")


def _short(name: str, keep: int = 40) -> str:
    """``name`` quoted, cut to its first ``keep`` characters when longer (for errors)."""
    return repr(name) if len(name) <= keep else f"{name[:keep]!r}..."


def normalise_shape(raw: str, *, where: str) -> str:
    try:
        return _SHAPE_ALIASES[raw.strip().lower()]
    except KeyError:
        raise SettingsError(f"{where}: shape {raw!r} is not one of {sorted(_SHAPE_ALIASES)}") from None


_REQUIRED = object()


def _typed(table: dict, key: str, kinds: tuple[type, ...], what: str, where: str, default=_REQUIRED):
    """``table[key]`` when it is one of ``kinds`` (never a bool for a number, nor an integer too large
    for a float); else SettingsError."""
    if key not in table:
        if default is _REQUIRED:
            raise SettingsError(f"{where}: key {key!r} is missing")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise SettingsError(f"{where}: {key} must be {what}, got {value!r}")
    if float in kinds:
        _check_float(value, key, what, where)
    return value


def _check_float(value: int | float, key: str, what: str, where: str) -> None:
    """SettingsError for a TOML integer too large for a float (float() would overflow), naming its
    digit count rather than its digits."""
    if isinstance(value, int) and abs(value) > sys.float_info.max:
        raise SettingsError(f"{where}: {key} holds an integer of {len(str(value))} digits, too large for a "
                            f"number: expected {what}")


def read_toml_catalogue(path: str | Path, *, recorded: bool = False) -> tuple[ObjectSpec, ...]:
    """Read the project's TOML catalogue; errors name the file, the object and the key.

    ``recorded``: a catalogue a session log holds, read for its labels (names, materials, shapes,
    moduli): the checks the simulator needs (a material of :data:`MATERIALS`, nothing but
    ``[[objects]]``, extents that agree with the shape) are left out, so a log recorded before them
    still reads.
    """
    path = Path(path)
    try:
        # utf-8-sig: editors on Windows save a byte-order mark, which tomllib refuses.
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise SettingsError(f"cannot read catalogue {path}: {exc.strerror or exc}") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SettingsError(f"{path}: not valid TOML: {exc}") from exc
    extra = sorted(set(data) - {"objects"})
    if extra and not recorded:
        raise SettingsError(f"{path}: unknown top-level key or table {extra[0]!r}; a catalogue holds only "
                            "[[objects]] tables (one per object)")
    tables = data.get("objects")
    if not isinstance(tables, list) or not tables:
        raise SettingsError(f"{path}: expected one or more [[objects]] tables")
    allowed = {"name", "shape", "material", "modulus_pa", "poisson", "size_m", "texture_m", "source"}
    number = (int, float)
    objects = []
    for i, table in enumerate(tables):
        where = f"{path}: objects[{i}]"
        if not isinstance(table, dict):
            raise SettingsError(f"{where}: expected an [[objects]] table, got {table!r}")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise SettingsError(f"{where}: unknown key {unknown[0]!r}; allowed keys: {', '.join(sorted(allowed))}")
        name = _typed(table, "name", (str,), "a string", where)
        where = f"{where} ({name if len(name) <= 40 else name[:40] + '...'})"
        size = _typed(table, "size_m", (list,), "an array of three extents in m", where, default=[])
        if not all(isinstance(s, number) and not isinstance(s, bool) for s in size):
            raise SettingsError(f"{where}: size_m must hold numbers (m), got {size!r}")
        for extent in size:
            _check_float(extent, "size_m", "numbers (m)", where)
        if not recorded:
            _check_section(table.get("shape"), size, where)
        try:
            objects.append(
                ObjectSpec(
                    name=name,
                    shape=normalise_shape(_typed(table, "shape", (str,), "a string", where), where=where),
                    material=_material(_typed(table, "material", (str,), "a string", where), where,
                                       known=not recorded),
                    modulus_pa=float(_typed(table, "modulus_pa", number, "a number (Pa)", where)),
                    poisson=float(_typed(table, "poisson", number, "a number", where, default=0.4)),
                    size_m=tuple(float(s) for s in size) if "size_m" in table else None,
                    texture_m=float(_typed(table, "texture_m", number, "a number (m)", where, default=0.0)),
                    source=_typed(table, "source", (str,), "a string", where, default=""),
                )
            )
        except ValueError as exc:
            if isinstance(exc, SettingsError):
                raise
            raise SettingsError(f"{where}: {exc}") from exc
    _check_unique(objects, path)
    return tuple(objects)


def _material(raw: str, where: str, *, known: bool) -> str:
    """``raw`` stripped and lower-cased; SettingsError when ``known`` and it is not one of :data:`MATERIALS`."""
    material = raw.strip().lower()
    if known and material not in MATERIALS:
        raise SettingsError(f"{where}: material {raw!r} is not one of {', '.join(MATERIALS)} (the simulator "
                            "takes its texture and densification from the material)")
    return material


def _check_section(shape: object, size: list, where: str) -> None:
    """Refuse a sphere's, cylinder's or hex prism's extents that the simulator would ignore (module notes)."""
    if not isinstance(shape, str) or len(size) != 3 or not all(s > 0 for s in size):
        return  # ObjectSpec and normalise_shape say what is wrong
    kind = _SHAPE_ALIASES.get(shape.strip().lower())
    if kind == "sphere":
        if any(abs(s - size[0]) > SECTION_TOLERANCE * size[0] for s in size[1:]):
            raise SettingsError(f"{where}: size_m {list(size)!r}: a sphere's three extents are its diameter, "
                                f"expected [{size[0]:g}, {size[0]:g}, {size[0]:g}] m (the simulator reads "
                                "size_m[0] only)")
        return
    if kind not in ("cylinder", "hex_prism"):
        return
    expected = size[0] if kind == "cylinder" else size[0] / math.cos(math.radians(30.0))
    if abs(size[1] - expected) > SECTION_TOLERANCE * expected:
        what = ("a cylinder is round: size_m[1] is its diameter, as size_m[0]" if kind == "cylinder" else
                "a hex prism is regular: size_m[1] is its width across corners, size_m[0] / cos 30")
        raise SettingsError(f"{where}: size_m {list(size)!r}: {what}, expected {expected:.4g} m, got "
                            f"{size[1]:g} m (size_m is [{'diameter, diameter' if kind == 'cylinder' else 'across flats, across corners'}"
                            ", length])")


def read_object_table(path: str | Path, *, skip_unlabelled: bool = True,
                      unlabelled: list[str] | None = None) -> tuple[ObjectSpec, ...]:
    """Read the published object table (CSV with ``Label``, ``Shape``, ``Material``, ``Modulus [Pa]``).

    Rows whose modulus is zero or empty are unlabelled: skipped by default (their labels are
    appended to ``unlabelled`` when given), an error with ``skip_unlabelled=False``; a table whose
    every row is unlabelled is an error. A negative, nan or infinite modulus, a row that ends
    before one of those four columns, or a header naming a column twice is an error naming the
    file (and line). A ``Radius [m]`` makes a sphere's size known, and a cylinder's as
    ``(d, d, d)``: its length is taken as its diameter (module notes).
    """
    path = Path(path)
    required = ("Label", "Shape", "Material", "Modulus [Pa]")
    try:
        # utf-8-sig: a spreadsheet's "CSV UTF-8" export starts with a byte-order mark, else glued to "Label".
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            rows = list(reader)
            columns = reader.fieldnames or []
    except OSError as exc:
        raise SettingsError(f"cannot read object table {path}: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise SettingsError(f"{path}: not a readable UTF-8 CSV table ({exc})") from exc
    twice = sorted({col for col in columns if col and columns.count(col) > 1})
    if twice:
        # csv.DictReader keeps the last of the two cells: an empty one would hide every row's value.
        raise SettingsError(f"{path}: the CSV header names column {twice[0]!r} {columns.count(twice[0])} times; "
                            "expected each column once: remove or rename the copies")
    missing = [col for col in required if col not in columns]
    if missing:
        hint = ("; the header holds ';': expected a comma-separated table (re-export it with ',' as the "
                "delimiter)" if any(";" in (col or "") for col in columns) else "")
        raise SettingsError(
            f"{path}: expected a CSV header with columns {', '.join(required)}; missing {', '.join(missing)}{hint}"
        )
    if not rows:
        raise SettingsError(f"{path}: the object table has a header but no rows")
    objects = []
    skipped = []
    for line, row in enumerate(rows, start=2):
        where = f"{path}:{line}"
        # A short row leaves None in the columns it lacks; only trailing optional ones may be left out,
        # else a cut row would pass for an unlabelled one.
        short = [col for col in required if row[col] is None]
        if short:
            raise SettingsError(f"{where}: the row ends before column {short[0]!r}; expected cells for "
                                f"{', '.join(required)} at least")
        cell = {key: (value or "").strip() for key, value in row.items() if isinstance(key, str)}
        if not cell["Label"]:
            raise SettingsError(f"{where}: the Label column is empty")
        text = cell["Modulus [Pa]"]
        try:
            modulus = float(text) if text else 0.0
        except ValueError:
            raise SettingsError(f"{where}: Modulus [Pa] {text!r} is not a number") from None
        if modulus == 0:
            if skip_unlabelled:
                skipped.append(cell["Label"])
                continue
            raise SettingsError(f"{where}: object {cell['Label']!r} has no usable Modulus [Pa] ({text!r}): "
                                "it is unlabelled")
        if modulus < 0 or not math.isfinite(modulus):
            raise SettingsError(f"{where}: object {cell['Label']!r}: Modulus [Pa] {text!r} is not a modulus; "
                                "expected a finite number > 0 (or 0 or empty for an unlabelled object)")
        if not MODULUS_RANGE_PA[0] <= modulus <= MODULUS_RANGE_PA[1]:
            raise SettingsError(f"{where}: object {cell['Label']!r}: Modulus [Pa] {text!r} is outside the "
                                f"plausible range {MODULUS_RANGE_PA[0]:g} to {MODULUS_RANGE_PA[1]:g} Pa")
        shape = normalise_shape(cell["Shape"], where=where)
        radius_text = cell.get("Radius [m]", "")
        size = None
        if radius_text and shape in ("sphere", "cylinder"):
            try:
                d = 2.0 * float(radius_text)
            except ValueError:
                raise SettingsError(f"{where}: Radius [m] {radius_text!r} is not a number") from None
            size = (d, d, d)
        try:
            objects.append(
                ObjectSpec(
                    name=cell["Label"],
                    shape=shape,
                    material=cell["Material"].lower(),  # kept, not checked against MATERIALS (module notes)
                    modulus_pa=modulus,
                    size_m=size,
                    source=cell.get("Notes", ""),
                )
            )
        except ValueError as exc:
            raise SettingsError(f"{where}: {exc}") from exc
    if not objects:
        raise SettingsError(f"{path}: every one of its {len(rows)} rows is unlabelled (Modulus [Pa] empty or 0): "
                            "expected at least one object with a modulus")
    _check_unique(objects, path)
    if unlabelled is not None:
        unlabelled.extend(skipped)
    return tuple(objects)


def load_catalogue(path: str | Path | None = None, *, unlabelled: list[str] | None = None,
                   recorded: bool = False) -> tuple[ObjectSpec, ...]:
    """Read either catalogue format, chosen by suffix (``.toml`` or ``.csv``); a CSV table's rows
    skipped as unlabelled are appended to ``unlabelled`` when given (a TOML catalogue has none).
    ``recorded``: one a session log holds (:func:`read_toml_catalogue`)."""
    path = Path(path) if path is not None else default_catalogue_path()
    if path.suffix.lower() == ".csv":
        return read_object_table(path, unlabelled=unlabelled)
    if path.suffix.lower() == ".toml":
        return read_toml_catalogue(path, recorded=recorded)
    raise SettingsError(f"{path}: unknown catalogue format; expected a .toml catalogue or a .csv object table")


def _check_unique(objects: list[ObjectSpec], path: Path) -> None:
    seen: set[str] = set()
    for obj in objects:
        if obj.name in seen:
            raise SettingsError(f"{path}: object name {obj.name!r} appears twice")
        seen.add(obj.name)
