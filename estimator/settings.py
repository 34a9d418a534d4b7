"""The estimator's own settings: the ``[estimator]`` table of the settings file.

Built from a loaded :class:`~teleop.settings.Settings` by :func:`estimator_settings`, which checks
what only the whole settings know: the depth binning against the estimating finger's sensor, and
the contact force against the gripper's target force. The finger and the objects' Poisson ratio
are ``[sensing]``, shared with the display.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from estimator.analytical import METHODS
from teleop.errors import SettingsError
from teleop.scene import current_method
from teleop.settings import Section, SensorSettings, Settings
from teleop.settings_fields import spec

__all__ = ["DEFAULT_METHODS", "EstimatorSettings", "configured_methods", "depth_binning_problem",
           "estimator_settings"]

#: The analytical fits run when ``methods`` names none, in order of preference.
DEFAULT_METHODS = ("series", "hertz", "elastic", "no_tactile")


def depth_binning_problem(binning: Any, sensor: SensorSettings | None = None, *,
                          grid_shape: tuple[int, int] | None = None) -> str | None:
    """Why ``binning`` cannot be a depth binning (:attr:`EstimatorSettings.depth_binning`), or None.

    A binning K is a whole number >= 1 dividing both sides of what it bins: ``sensor``'s image
    grid and its raw frame (decoded K times smaller), and ``grid_shape`` (rows, cols; e.g. a
    calibration's grid). K above 1 is refused for a sensor with markers: their dots are found and
    inpainted on the full grid only. The one statement of the rule: the settings, the warp and the
    depth grid (``estimator.perception``) all ask it and raise their own error with its answer.
    """
    if isinstance(binning, bool) or not isinstance(binning, int) or binning < 1:
        return f"expected a whole number >= 1, got {binning!r}"
    if sensor is not None:
        (rows, cols), raw = sensor.image_shape, (sensor.raw_height_px, sensor.raw_width_px)
        if any(side % binning for side in (rows, cols, *raw)):
            return (f"does not divide the {rows} x {cols} px image grid and the {raw[0]} x {raw[1]} px raw "
                    f"frame of finger {sensor.finger!r}; choose a common divisor or 1")
        if binning > 1 and sensor.markers:
            return (f"finger {sensor.finger!r} has markers, which are found and inpainted on the full grid "
                    "only: measure it with binning 1 (depth_binning = 1)")
    if grid_shape is not None and any(side % binning for side in grid_shape):
        return f"does not divide both sides of the {grid_shape[0]} x {grid_shape[1]} px grid"
    return None


@dataclass(frozen=True)
class EstimatorSettings(Section):
    """Grasp segmentation and estimation defaults."""

    TABLE = "estimator"
    PATHS = ("model_path",)
    MOVED = {"finger": "[sensing] finger", "object_poisson": "[sensing] object_poisson"}

    contact_force_n: float = spec(0.75, lo=0.0, hi=100.0, lo_open=True, doc="first-contact force")
    n_frames: int = spec(3, lo=1, hi=64)
    methods: tuple[str, ...] = spec(DEFAULT_METHODS, choices=METHODS,
                                    doc="the analytical fits the service runs, in order of preference")
    model_path: str = spec("", doc="ONNX model; empty means the shipped default")
    depth_binning: int = spec(2, lo=1, hi=16, doc="depth is measured on the finger's image grid averaged over "
                              "N x N px blocks (1: the full grid); a model is trained for one value")

    def __post_init__(self) -> None:
        if isinstance(self.methods, tuple):
            object.__setattr__(self, "methods", tuple(current_method(m) for m in self.methods))
        super().__post_init__()

    def resolved(self, settings: Settings) -> EstimatorSettings:
        """Checked against the estimating finger's sensor (its image grid divides by the binning) and
        the gripper's target force (a commanded grasp reaches the contact force)."""
        problem = depth_binning_problem(self.depth_binning, settings.sensor(settings.sensing.finger))
        if problem:
            raise SettingsError(f"EstimatorSettings.depth_binning = {self.depth_binning}: {problem}")
        # The segmenter starts a grasp's loading phase where its force first reaches contact_force_n
        # and refuses a grasp that never does: a commanded grasp, squeezing to the target, must pass it.
        target = settings.gripper.target_force_n
        if target <= self.contact_force_n:
            raise SettingsError(
                f"gripper.target_force_n = {target:g} N is not above estimator.contact_force_n = "
                f"{self.contact_force_n:g} N: a grasp that never reaches the contact force gives no estimate; "
                "raise gripper.target_force_n or lower estimator.contact_force_n")
        return self


def estimator_settings(settings: Settings) -> EstimatorSettings:
    """The ``[estimator]`` table of ``settings``, checked against the rig."""
    return settings.section(EstimatorSettings)


def configured_methods(settings: Settings) -> tuple[str, ...]:
    """The analytical methods ``estimator.methods`` names (each checked when the settings are
    read), or the defaults when it names none."""
    return estimator_settings(settings).methods or DEFAULT_METHODS
