"""The estimator's own settings: the ``[estimator]`` table of the settings file.

Built from a loaded :class:`~teleop.settings.Settings` by :func:`estimator_settings`, which checks
what only the whole settings know: the depth binning against the estimating finger's sensor. The
finger and the objects' Poisson ratio are ``[sensing]``, shared with the display.
"""

from __future__ import annotations

from dataclasses import dataclass

from estimator.analytical import METHODS
from teleop.errors import SettingsError
from teleop.settings import Section, Settings, depth_binning_problem
from teleop.settings_fields import spec

__all__ = ["DEFAULT_METHODS", "EstimatorSettings", "configured_methods", "estimator_settings"]

#: The analytical fits run when ``methods`` names none, in order of preference.
DEFAULT_METHODS = ("split", "hertz", "elastic", "no_tactile")


@dataclass(frozen=True)
class EstimatorSettings(Section):
    """Grasp segmentation and estimation defaults."""

    TABLE = "estimator"
    PATHS = ("model_path",)

    contact_force_n: float = spec(0.75, lo=0.0, hi=100.0, lo_open=True, doc="first-contact force")
    n_frames: int = spec(3, lo=1, hi=64)
    methods: tuple[str, ...] = spec(DEFAULT_METHODS, choices=METHODS,
                                    doc="the analytical fits the service runs, in order of preference")
    model_path: str = spec("", doc="ONNX model; empty means the shipped default")
    depth_binning: int = spec(2, lo=1, hi=16, doc="depth is measured on the finger's image grid averaged over "
                              "N x N px blocks (1: the full grid); a model is trained for one value")

    def resolved(self, settings: Settings) -> EstimatorSettings:
        """Checked against the estimating finger's sensor (its image grid divides by the binning)."""
        problem = depth_binning_problem(self.depth_binning, settings.sensor(settings.sensing.finger))
        if problem:
            raise SettingsError(f"EstimatorSettings.depth_binning = {self.depth_binning}: {problem}")
        return self


def estimator_settings(settings: Settings) -> EstimatorSettings:
    """The ``[estimator]`` table of ``settings``, checked against the rig."""
    return settings.section(EstimatorSettings)


def configured_methods(settings: Settings) -> tuple[str, ...]:
    """The analytical methods ``estimator.methods`` names (each checked when the settings are
    read), or the defaults when it names none."""
    return estimator_settings(settings).methods or DEFAULT_METHODS
