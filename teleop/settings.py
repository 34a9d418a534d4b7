"""Typed, validated settings, loaded from one explicit TOML file.

Each device family has a frozen dataclass whose fields carry their allowed
range in ``field`` metadata; values are checked on construction, so an
invalid settings object cannot exist. :func:`load_settings` reads one TOML
file and nothing else (no environment variables, no home-directory files):
an unknown key, a wrong type or an out-of-range value raises
:class:`~teleop.errors.SettingsError` naming the file, the key and what is
allowed.

Each package owns its tables. This base owns the rig's: ``[sensors.<finger>]``, ``[sensing]``,
``[gripper]``, ``[load_cell]``, ``[bus]`` and ``[simulation]``. A package above it registers its
own table by name in the ``compliance_teleop.settings_tables`` entry-point group (pyproject.toml:
``[estimator]``, ``[display]``, ``[operator]``); the base keeps such tables as read, and their
owners build, check and complete them (:meth:`Settings.section`), so the base names and imports
none of them. A relative path in a file resolves against the file's folder (:func:`resolve_path`;
through a symbolic link, the folder of the file it points to: :func:`settings_folder`).

All quantities are SI (m, N, Pa, s, Hz) unless the name says otherwise.

The sensor's resolution limit (the stiffest object its gel tells apart) is derived in
:mod:`teleop.physics`.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import os
import re
import tomllib
import types
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from teleop.endpoints import BUS_TRANSPORTS, ENDPOINT_FORMS, Endpoint, parse_endpoint, same_socket
from teleop.errors import SettingsError
from teleop.physics import resolution_limit_pa
from teleop.settings_fields import Validated, build_settings, spec, tcp_host_port
from teleop.settings_paths import (
    CONFIG_DIR,
    config_dir,
    default_settings_path,
    resolve_path,
    settings_folder,
)

__all__ = [
    "BusSettings",
    "CONFIG_DIR",
    "GripperSettings",
    "LoadCellSettings",
    "Section",
    "SensingSettings",
    "SensorSettings",
    "Settings",
    "SimulationSettings",
    "TABLES_GROUP",
    "config_dir",
    "default_settings_path",
    "load_settings",
    "migrated",
    "package_sections",
    "package_tables",
    "resolve_path",
    "settings_folder",
    "settings_from_mapping",
    "settings_to_mapping",
    "shipped_calibration_hint",
]


@dataclass(frozen=True)
class SensorSettings(Validated):
    """One GelSight-style tactile sensor: camera geometry, warp and gel."""

    finger: str = spec("left", doc="which finger carries it")
    model: str = spec("wedge", choices=("wedge", "mini"),
                      doc="wedge: raw frames warped by the mirror corners and cropped; mini: a flat sensor "
                          "whose raw frame is the image (no warp, no crop)")
    optics: str = spec("wedge", choices=("wedge", "gelsight", "gelsight_mini"),
                       doc="how the simulator renders this sensor's frames (teleop.sim): 'wedge', the "
                           "GelSight Wedge appearance model (teleop/sim/wedge_optics.py); 'gelsight' or "
                           "'gelsight_mini', the measured colour tables and no-contact frame of a real "
                           "GelSight R1.5 or GelSight Mini (teleop/sim/table_optics.py). Not read by "
                           "real cameras or the estimator")
    serial: str = spec("", doc="sensor identity, recorded with every grasp")
    calibration: str = spec("", doc="colour-to-gradient calibration (.npz from `estimator calibrate`); "
                                    "a relative path is against the settings file's folder")
    markers: bool = spec(False, doc="gel printed with marker dots")
    camera_backend: str = spec("sim", choices=("sim", "opencv"), doc="camera driver (teleop.devices.camera)")
    camera_source: str = spec("", doc="opencv: device index ('0') or MJPG URL (http://pi:8080/?action=stream)")
    camera_hz: float = spec(30.0, lo=1.0, hi=240.0)
    camera_latency_s: float = spec(0.0, lo=-1.0, hi=1.0,
                                   doc="how much later this camera stamps a frame than the load cell stamps "
                                       "the same event (s; measured from a tap by `teleop calibrate camera "
                                       "--latency`); the camera subtracts it from every frame's time")
    raw_width_px: int = spec(640, lo=16, hi=4096)
    raw_height_px: int = spec(480, lo=16, hi=4096)
    # Mirror-corner calibration in raw pixels: top-left, top-right, bottom-left, bottom-right.
    warp_corners_px: tuple[tuple[float, float], ...] = spec(
        ((46.0, 87.0), (439.0, 121.0), (52.0, 425.0), (446.0, 368.0)), lo=-4096, hi=8192, length=4
    )
    warped_width_px: int = spec(400, lo=16, hi=4096)
    warped_height_px: int = spec(300, lo=16, hi=4096)
    crop_px: int = spec(25, lo=0, hi=1000, doc="pixels cropped from every side after the warp")
    pixel_pitch_m: float = spec(1.0 / 11.0 * 1e-3, lo=1e-6, hi=1e-3, doc="gel surface per warped pixel")
    gel_modulus_pa: float = spec(0.275e6, lo=1e3, hi=1e8, lo_open=True)
    gel_poisson: float = spec(0.48, lo=0.0, hi=0.5)
    gel_thickness_m: float = spec(3.0e-3, lo=1e-4, hi=2e-2, lo_open=True)
    contact_threshold_m: float = spec(0.1e-3, lo=0.0, hi=5e-3, lo_open=True)
    depth_resolution_m: float = spec(0.02e-3, lo=0.0, hi=1e-3, lo_open=True,
                                     doc="smallest depth step the sensor resolves")
    depth_scale_uncertainty: float = spec(0.05, lo=0.0, hi=1.0,
                                          doc="relative scale error of reconstructed depth")

    def _check(self) -> None:
        if self.model == "wedge" and 2 * self.crop_px >= min(self.warped_width_px, self.warped_height_px):
            raise SettingsError(
                f"SensorSettings.crop_px = {self.crop_px}: crops the whole "
                f"{self.warped_width_px}x{self.warped_height_px} warped image away"
            )
        if self.model == "wedge":  # a flat sensor ("mini") is not warped: its corners are not read
            self._check_corners()

    def _check_corners(self) -> None:
        """The mirror corners lie in the raw frame (its edges included) and, in their order (top-left,
        top-right, bottom-left, bottom-right), outline a convex quadrilateral: not one that crosses
        itself (two corners swapped) or bends inward, whose warp folds the image."""
        corners = self.warp_corners_px
        where = f"SensorSettings.warp_corners_px = {[list(c) for c in corners]}"
        for name, (x, y) in zip(("top-left", "top-right", "bottom-left", "bottom-right"), corners, strict=True):
            if not (0.0 <= x <= self.raw_width_px and 0.0 <= y <= self.raw_height_px):
                raise SettingsError(
                    f"{where}: the {name} corner ({x:g}, {y:g}) is outside the {self.raw_width_px}x"
                    f"{self.raw_height_px} raw frame: expected x in [0, {self.raw_width_px}] and y in "
                    f"[0, {self.raw_height_px}] (raw_width_px x raw_height_px)"
                )
        top_left, top_right, bottom_left, bottom_right = corners
        outline = (top_left, top_right, bottom_right, bottom_left)  # walked round: clockwise on screen
        for i in range(4):
            (ax, ay), (bx, by), (cx, cy) = outline[i], outline[(i + 1) % 4], outline[(i + 2) % 4]
            if (bx - ax) * (cy - by) - (by - ay) * (cx - bx) <= 0.0:
                raise SettingsError(
                    f"{where}: expected the corners in the order top-left, top-right, bottom-left, "
                    "bottom-right of a convex quadrilateral; these cross, bend inward or lie on a line "
                    "(two corners swapped?)"
                )

    @property
    def image_shape(self) -> tuple[int, int]:
        """(rows, cols) of the image the estimator works on: a Wedge's warped and cropped frame; a
        flat sensor's (``model = "mini"``: no mirror, no warp) raw frame as it comes."""
        if self.model == "mini":
            return (self.raw_height_px, self.raw_width_px)
        return (self.warped_height_px - 2 * self.crop_px, self.warped_width_px - 2 * self.crop_px)

    @property
    def pad_size_m(self) -> tuple[float, float]:
        """(height, width) of the imaged gel area in metres."""
        rows, cols = self.image_shape
        return (rows * self.pixel_pitch_m, cols * self.pixel_pitch_m)

    @property
    def gel_compliance_per_pa(self) -> float:
        """k = (1 - nu^2) / E of the gel, in 1/Pa."""
        return (1.0 - self.gel_poisson**2) / self.gel_modulus_pa

    def resolution_limit_pa(self, object_poisson: float) -> float:
        """E (Pa) above which this sensor cannot tell objects apart (:mod:`teleop.physics`), for an
        object of Poisson ratio ``object_poisson``."""
        return resolution_limit_pa(gel_thickness_m=self.gel_thickness_m, depth_resolution_m=self.depth_resolution_m,
                                   gel_compliance_per_pa=self.gel_compliance_per_pa, object_poisson=object_poisson)


#: A host name or an IP address (v6 with a zone too): no scheme, port, path or spaces.
_HOST = re.compile(r"[A-Za-z0-9._:%-]+")


MIN_FINGER_STIFFNESS_N_PER_M = 1e3  # 1 N/mm: far below any real finger, far above a value typed in N/mm


@dataclass(frozen=True)
class GripperSettings(Validated):
    """Parallel gripper motion and grasp parameters."""

    backend: str = spec("sim", choices=("sim", "franky"))
    host: str = spec("127.0.0.1", doc="robot controller address (franky)")
    connect_timeout_s: float = spec(5.0, lo=0.0, hi=60.0, lo_open=True,
                                    doc="how long connecting may take before the robot counts as not answering "
                                        "(franky; libfranka's own limit is 60 s)")
    max_width_m: float = spec(0.08, lo=0.0, hi=0.3, lo_open=True)
    closing_speed_m_s: float = spec(0.0375, lo=0.0, hi=0.2, lo_open=True)
    target_force_n: float = spec(30.0, lo=0.0, hi=140.0, lo_open=True)
    hold_s: float = spec(0.5, lo=0.0, hi=60.0)
    width_read_hz: float = spec(10.0, lo=0.1, hi=1000.0)
    finger_stiffness_n_per_m: float = spec(2.0e5, lo=0.0, hi=1e9, lo_open=True,
                                           doc="finger bending stiffness, corrected from force")

    def _check(self) -> None:
        # checked as the file loads, not first when franky connects (libfranka: "Host not found")
        if not _HOST.fullmatch(self.host):
            raise SettingsError(f"GripperSettings.host = {self.host!r}: expected the robot controller's host name "
                                "or IP address, e.g. '172.16.0.2'")
        # N/mm typed as N/m (200 for 2e5): fingers with a gel pad are 2e4-5e5 N/m; below 1 N/mm the width
        # correction (F / stiffness) would be centimetres at a few newtons, swamping the width measured
        if self.finger_stiffness_n_per_m < MIN_FINGER_STIFFNESS_N_PER_M:
            raise SettingsError(
                f"GripperSettings.finger_stiffness_n_per_m = {self.finger_stiffness_n_per_m!r}: expected at least "
                f"{MIN_FINGER_STIFFNESS_N_PER_M:g} N/m (fingers with a gel pad are 2e4-5e5 N/m); a value in N/mm "
                f"is 1000x too small: {self.finger_stiffness_n_per_m:g} N/mm is "
                f"{self.finger_stiffness_n_per_m * 1e3:g} N/m"
            )


@dataclass(frozen=True)
class LoadCellSettings(Validated):
    """HX711 load cell: sample rate, calibration and transport."""

    backend: str = spec("sim", choices=("sim", "serial", "tcp"))
    sample_rate_hz: float = spec(80.0, choices=(10.0, 80.0))
    counts_per_n: float = spec(4.2e4, lo=0.0, hi=1e9, lo_open=True, doc="scale factor")
    tare_counts: int = spec(0, lo=-(2**23), hi=2**23 - 1)
    port: str = spec("", doc="serial device path (serial backend)")
    baud: int = spec(115200, lo=1200, hi=4_000_000)
    address: str = spec("tcp://127.0.0.1:5601", doc="framed TCP endpoint (tcp backend)")
    timeout_s: float = spec(1.0, lo=0.0, hi=60.0, lo_open=True)

    def _check(self) -> None:
        # as the file loads, not first when the tcp backend connects
        if tcp_host_port(self.address) is None:
            raise SettingsError(f"LoadCellSettings.address = {self.address!r}: expected tcp://HOST:PORT with a port in "
                                "1..65535, where `teleop hx711-bridge` serves")


@dataclass(frozen=True)
class BusSettings(Validated):
    """ZeroMQ endpoints and limits.

    Each endpoint is bound by one process and connected to by the others (robot_pub: the robot
    node; estimate_pub: the estimator; command: the operator; display_pub: the haptic renderer;
    control: ``estimator reload``), so no two may name the same one.
    """

    #: The fields that are bus endpoints.
    ENDPOINTS: ClassVar[tuple[str, ...]] = ("robot_pub", "estimate_pub", "command", "display_pub", "control")

    robot_pub: str = spec("tcp://127.0.0.1:5550", doc="robot node publishes grasp data here")
    estimate_pub: str = spec("tcp://127.0.0.1:5551", doc="estimator publishes estimates here")
    command: str = spec("tcp://127.0.0.1:5552", doc="operator grasp commands")
    display_pub: str = spec("tcp://127.0.0.1:5553", doc="haptic renderer publishes its heartbeat here")
    control: str = spec("tcp://127.0.0.1:5554", doc="one-off tools (estimator reload) send here while an "
                                                    "operator holds the command endpoint")
    heartbeat_s: float = spec(0.5, lo=0.0, hi=60.0, lo_open=True)
    max_message_bytes: int = spec(8 * 1024 * 1024, lo=1024, hi=2**31 - 1)
    keys_dir: str = spec("", doc="CURVE key directory (a relative one: against the settings file's folder); "
                              "required when an endpoint is not loopback")

    def _check(self) -> None:
        bound: dict[str, Endpoint] = {}
        for name in self.ENDPOINTS:
            value = getattr(self, name)
            try:
                endpoint = parse_endpoint(value)
            except ValueError as exc:
                raise SettingsError(f"BusSettings.{name} = {value!r}: {exc}") from None
            if endpoint.scheme not in BUS_TRANSPORTS:
                raise SettingsError(f"BusSettings.{name} = {value!r}: expected {ENDPOINT_FORMS}")
            for other, taken in bound.items():
                if same_socket(endpoint, taken):
                    # localhost is 127.0.0.1, and a wildcard host holds its port on every address
                    raise SettingsError(f"BusSettings.{name} = {value!r}: the same endpoint as {other} "
                                        f"({getattr(self, other)!r}), and each is bound by a process of its own: "
                                        "give each an endpoint of its own")
            bound[name] = endpoint


@dataclass(frozen=True)
class SimulationSettings(Validated):
    """Simulated hardware: noise and timing of the virtual sensors."""

    force_noise_n: float = spec(0.02, lo=0.0, hi=10.0)
    width_noise_m: float = spec(2e-5, lo=0.0, hi=1e-3)
    width_latency_s: float = spec(0.1, lo=0.0, hi=1.0)
    camera_offset_s: float = spec(0.015, lo=-1.0, hi=1.0, doc="camera clock minus robot clock")
    camera_noise: float = spec(2.0, lo=0.0, hi=50.0, doc="pixel noise standard deviation, 8-bit levels")
    jpeg_quality: int = spec(90, lo=10, hi=100)
    grid_px: int = spec(4, lo=1, hi=16, doc="contact solver cell size in image pixels")
    background: str = spec("", doc="no-contact frame PNG; empty means the optics' own (procedural for "
                                   "'wedge', the real sensor's recorded frame for table optics)")
    gel_model: str = spec("layer", choices=("layer", "half-space"),
                          doc="the gel in the contact solver: 'layer', an elastic layer of the sensor's "
                              "thickness bonded to a rigid backing (the sensor as built); 'half-space', "
                              "an unbounded elastic body, a contact model the estimator was not trained "
                              "on (teleop/sim/contact.py)")
    illumination_gain: float = spec(1.0, lo=0.5, hi=1.5,
                                    doc="scales the contact-induced colour change of every optics "
                                        "(LED current, ageing); the no-contact frame is unchanged")


@dataclass(frozen=True)
class SensingSettings(Validated):
    """What every estimate refers to: the finger whose sensor estimates, and the Poisson ratio
    assumed for grasped objects. With that sensor's gel they set the resolution limit (module
    notes), which is both the estimator's ``lower_bound`` and the display's rigid end."""

    finger: str = spec("left", doc="finger whose tactile frames the estimator reads")
    object_poisson: float = spec(0.4, lo=0.0, hi=0.5, doc="Poisson ratio assumed for grasped objects")


#: The entry-point group in which a package above this base registers its settings table: the
#: entry's name is the table's, its value the :class:`Section` that builds it.
TABLES_GROUP = "compliance_teleop.settings_tables"


@functools.cache
def package_tables() -> tuple[str, ...]:
    """The top-level tables the packages above this base registered (:data:`TABLES_GROUP`): the base
    keeps them as read, and each package builds and checks its own (:meth:`Settings.section`)."""
    return tuple(sorted(entry.name for entry in importlib.metadata.entry_points(group=TABLES_GROUP)))


def package_sections() -> tuple[type[Section], ...]:
    """The :class:`Section` classes the packages registered for their tables (imported by name only)."""
    return tuple(entry.load() for entry in importlib.metadata.entry_points(group=TABLES_GROUP))

S = TypeVar("S", bound="Section")


class Section(Validated):
    """Base of a package's own settings table: a frozen dataclass with its fields' ``spec``.

    ``TABLE`` names its table in the settings file, ``PATHS`` its fields holding file paths
    (resolved like every path of the file, :func:`resolve_path`), ``MOVED`` keys that moved to
    another table (key -> where it is now, ``"[table] key"``: said when a file still has it, and where
    :func:`migrated` carries it). :meth:`resolved` completes and checks it against the whole settings
    (rules across tables); the default has none.
    """

    TABLE: ClassVar[str] = ""
    PATHS: ClassVar[tuple[str, ...]] = ()
    MOVED: ClassVar[Mapping[str, str]] = {}

    def resolved(self: S, settings: Settings) -> S:  # noqa: ARG002 - the hook's signature
        return self


@dataclass(frozen=True)
class Settings(Validated):
    """Everything one deployment needs, as read from one TOML file.

    The base's own tables are fields; the packages' tables (:func:`package_tables`) are kept as read
    in ``tables`` and built by their owners through :meth:`section`. ``source`` is the file read
    (None when built in code): relative paths in it resolve against its folder.
    """

    sensors: tuple[SensorSettings, ...] = spec(
        default_factory=lambda: (SensorSettings(finger="left"), SensorSettings(finger="right", markers=True))
    )
    sensing: SensingSettings = spec(default_factory=SensingSettings)
    gripper: GripperSettings = spec(default_factory=GripperSettings)
    load_cell: LoadCellSettings = spec(default_factory=LoadCellSettings)
    bus: BusSettings = spec(default_factory=BusSettings)
    simulation: SimulationSettings = spec(default_factory=SimulationSettings)
    # Not keys of the file: the packages' tables keep their own names, and where the file was.
    tables: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict, metadata={"key": False})
    source: Path | None = dataclasses.field(default=None, compare=False, repr=False, metadata={"key": False})

    def _check(self) -> None:
        fingers = [s.finger for s in self.sensors]
        if not fingers:
            raise SettingsError("Settings.sensors is empty: expected at least one [sensors.<finger>] table")
        if len(set(fingers)) != len(fingers):
            raise SettingsError(f"Settings.sensors names a finger twice: {fingers}")
        if self.sensing.finger not in fingers:
            raise SettingsError(f"SensingSettings.finger = {self.sensing.finger!r}: expected a finger with a "
                                f"sensor, one of {fingers}")
        unknown = sorted(set(self.tables) - set(package_tables()))
        if unknown:
            raise SettingsError(f"Settings.tables names {unknown[0]!r}: expected some of "
                                f"{', '.join(package_tables()) or 'none (is the project installed?)'}")

    def __hash__(self) -> int:  # the packages' tables are plain dicts: hash a frozen copy
        own = tuple(getattr(self, f.name) for f in dataclasses.fields(self) if f.metadata.get("key", True))
        return hash((own, _frozen(self.tables)))

    @property
    def folder(self) -> Path:
        """Where relative paths of these settings point from (:func:`settings_folder`)."""
        return settings_folder(self.source)

    @property
    def resolution_limit_pa(self) -> float:
        """E (Pa) above which the estimating finger cannot tell objects apart (module notes)."""
        return self.sensor(self.sensing.finger).resolution_limit_pa(self.sensing.object_poisson)

    def sensor(self, finger: str) -> SensorSettings:
        """The sensor on ``finger``; raises SettingsError naming the fingers there are."""
        for s in self.sensors:
            if s.finger == finger:
                return s
        raise SettingsError(
            f"no sensor on finger {finger!r}: settings have {[s.finger for s in self.sensors]}"
        )

    def section(self, cls: type[S]) -> S:
        """The package table ``cls.TABLE`` as a ``cls``: built from the file's table (defaults where
        it has none), its paths resolved, completed by :meth:`Section.resolved`; built once.

        Raises SettingsError naming the file and the key when the table is invalid.
        """
        cache = self.__dict__.setdefault("_sections", {})  # frozen: the cache is not a field
        if cls not in cache:
            where = str(self.source or "<settings>")
            table = dict(self.tables.get(cls.TABLE, {}))
            for key in table:
                if key in cls.MOVED:
                    raise SettingsError(f"{where}: [{cls.TABLE}] {key} is now {cls.MOVED[key]}: move it there")
            for key in cls.PATHS:
                if isinstance(table.get(key), str) and table[key]:
                    table[key] = str(resolve_path(table[key], folder=self.folder))
            built = build_settings(cls, table, where, cls.TABLE)
            try:
                cache[cls] = built.resolved(self)
            except SettingsError as exc:
                raise SettingsError(f"{where}: [{cls.TABLE}] {exc}") from None
        return cache[cls]

    def with_section(self, section: Section) -> Settings:
        """These settings with ``section`` as its package's table, checked against them at once."""
        changed = dataclasses.replace(self, tables={**self.tables, section.TABLE: settings_to_mapping(section)})
        changed.section(type(section))
        return changed


# --------------------------------------------------------------------------- loading


def _build_settings_file(data: Mapping[str, Any], source: Path | None) -> Settings:
    """:class:`Settings` from a whole file's mapping: the packages' tables kept as read, paths of the
    base's tables resolved against the file's folder (:func:`resolve_path`)."""
    where = str(source or "<settings>")
    tables = {}
    for name in package_tables():
        if name not in data:
            continue
        table = data[name]
        if not isinstance(table, Mapping):
            raise SettingsError(f"{where}: [{name}] must be a table, got {type(table).__name__}")
        tables[name] = dict(table)
    own = {k: v for k, v in data.items() if k not in package_tables()}
    folder = settings_folder(source)
    sensors = own.get("sensors")
    if isinstance(sensors, Mapping):
        own["sensors"] = {finger: _with_path(table, "calibration", folder) for finger, table in sensors.items()}
    if isinstance(own.get("simulation"), Mapping):
        own["simulation"] = _with_path(own["simulation"], "background", folder)
    if isinstance(own.get("bus"), Mapping):
        own["bus"] = _with_path(own["bus"], "keys_dir", folder)
    built = {"sensors": _build_sensors(own["sensors"], where)} if "sensors" in own else {}
    settings = build_settings(Settings, own, where, "", built=built, others=package_tables())
    return dataclasses.replace(settings, tables=tables, source=source)


def _frozen(value: Any) -> Any:
    """A hashable copy of TOML-shaped data (tables and arrays become sorted tuples and tuples)."""
    if isinstance(value, Mapping):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    return value


def _with_path(table: Any, key: str, folder: Path) -> Any:
    if isinstance(table, Mapping) and isinstance(table.get(key), str) and table[key]:
        return {**table, key: str(resolve_path(table[key], folder=folder))}
    return table


def _build_sensors(value: Any, source: str) -> tuple[SensorSettings, ...]:
    """``[sensors.<finger>]`` tables become SensorSettings with ``finger`` filled in."""
    if not isinstance(value, Mapping):
        raise SettingsError(f"{source}: [sensors] must hold one table per finger, e.g. [sensors.left]")
    out = []
    for finger, table in value.items():
        if not isinstance(table, Mapping):
            raise SettingsError(f"{source}: [sensors.{finger}] must be a table")
        if "finger" in table and table["finger"] != finger:
            raise SettingsError(f"{source}: [sensors.{finger}] sets finger = {table['finger']!r}")
        out.append(build_settings(SensorSettings, {**table, "finger": finger}, source, f"sensors.{finger}"))
    return tuple(out)


def settings_from_mapping(data: Mapping[str, Any], *, source: str | Path | None = None) -> Settings:
    """Build validated :class:`Settings` from a TOML-shaped mapping; ``source`` is the file it was
    read from (relative paths resolve against its folder), or None (against :func:`config_dir`)."""
    return _build_settings_file(data, None if source is None else Path(source))


#: A :attr:`Section.MOVED` value: where the key is now, ``"[table] key"``.
_MOVED_TO = re.compile(r"\[(\w+)\] (\w+)")


def migrated(data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` (TOML-shaped) with the packages' moved keys (:attr:`Section.MOVED`) carried to where they
    are now, unless that table sets them itself: for settings that record what ran (a session log's),
    which nobody edits. A settings file the user edits is refused instead (:meth:`Settings.section`)."""
    out = dict(data)
    for cls in package_sections():
        table = out.get(cls.TABLE)
        if not isinstance(table, Mapping) or not cls.MOVED.keys() & table.keys():
            continue
        table = out[cls.TABLE] = dict(table)
        for key in sorted(cls.MOVED.keys() & table.keys()):
            match = _MOVED_TO.fullmatch(cls.MOVED[key])
            if match is None:
                raise SettingsError(f"{cls.__name__}.MOVED[{key!r}] = {cls.MOVED[key]!r}: expected "
                                    "'[table] key'")
            value, (name, new_key) = table.pop(key), match.groups()
            target = out.get(name, {})
            if isinstance(target, Mapping):  # else building names the table that is not one
                out[name] = {new_key: value, **target}
    return out


def settings_to_mapping(settings: Any) -> dict[str, Any]:
    """Plain-data form (dicts, lists, numbers, strings) of any settings object.

    ``settings_from_mapping(settings_to_mapping(s)) == s`` for :class:`Settings`.
    """
    if isinstance(settings, Settings):
        out = {f.name: settings_to_mapping(getattr(settings, f.name)) for f in dataclasses.fields(settings)
               if f.metadata.get("key", True)}
        out["sensors"] = {s.finger: settings_to_mapping(s) for s in settings.sensors}
        return {**out, **settings_to_mapping(dict(settings.tables))}
    if dataclasses.is_dataclass(settings):
        return {f.name: settings_to_mapping(getattr(settings, f.name)) for f in dataclasses.fields(settings)}
    if isinstance(settings, tuple | list):
        return [settings_to_mapping(v) for v in settings]
    if isinstance(settings, types.MappingProxyType | dict):
        return {k: settings_to_mapping(v) for k, v in settings.items()}
    return settings


def load_settings(path: str | Path | None = None) -> Settings:
    """Load settings from exactly one TOML file (the shipped default when ``path`` is None).

    Raises
    ------
    SettingsError
        The file is missing or not TOML, or a key is unknown, mistyped or out of range;
        the message names the file and the key.
    """
    path = Path(path) if path is not None else default_settings_path()
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SettingsError(f"cannot read settings file {path}: {exc.strerror or exc}") from exc
    try:
        data = tomllib.loads(raw.decode("utf-8-sig"))  # a byte-order mark (some Windows editors) is no statement
    except ValueError as exc:  # TOMLDecodeError, UnicodeDecodeError, or an integer of over 4300 digits
        raise SettingsError(f"{path}: not valid TOML: {exc}") from exc
    return settings_from_mapping(data, source=Path(os.path.abspath(path)))


def missing_calibrations(settings: Settings, path: str | Path | None = None) -> list[str]:
    """Why each sensor's calibration file, named in ``settings`` (loaded from ``path``; None: the
    shipped file), is missing, or why the estimating finger's is (none named): valid settings, but
    the estimator refuses their sensor's frames."""
    folder = settings_folder(Path(path or default_settings_path()))
    estimating = settings.sensor(settings.sensing.finger)
    unnamed = [] if estimating.calibration else [
        f"[sensors.{estimating.finger}] calibration: none named, and [sensing] finger = "
        f"{estimating.finger!r} estimates; make one with `estimator calibrate` and name it there"]
    return unnamed + [f"[sensors.{sensor.finger}] calibration {sensor.calibration}: no such file (a relative path "
                      f"resolves against {folder}); {_make_calibration(sensor)}"
                      for sensor in settings.sensors if sensor.calibration and not Path(sensor.calibration).is_file()]


def _make_calibration(sensor: SensorSettings) -> str:
    hint = shipped_calibration_hint(sensor)
    return "make it with `estimator calibrate`" if hint is None else f"{hint}, or make your own with `estimator calibrate`"


def shipped_calibration_hint(sensor: SensorSettings) -> str | None:
    """Where ``sensor``'s missing calibration file is shipped (``config_dir()/calibration``, by its file
    name): "the shipped one is PATH: point [sensors.FINGER] calibration at it"; None when the file is
    there, none is named, or none of that name is shipped. A copy of the shipped settings elsewhere
    names the simulated sensors' files relative to the copy's folder: they need no capture."""
    path = Path(sensor.calibration)
    if not sensor.calibration or path.is_file():
        return None
    shipped = config_dir() / "calibration" / path.name
    if not shipped.is_file():
        return None
    return f"the shipped one is {shipped}: point [sensors.{sensor.finger}] calibration at it"
