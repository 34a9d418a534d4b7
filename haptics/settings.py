"""The display's own settings: the ``[display]`` table of the settings file.

Built from a loaded :class:`~teleop.settings.Settings` by :func:`display_settings`, which
completes the rigid end: ``e_rigid_pa = 0`` (the default) stands for the sensor's resolution
limit (:attr:`teleop.settings.Settings.resolution_limit_pa`), beyond which the estimator reports
only a lower bound, so anything at or above it is rendered rigid.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from teleop.errors import SettingsError
from teleop.settings import Section, Settings
from teleop.settings_fields import spec

__all__ = ["DisplaySettings", "display_range_pa", "display_settings"]


@dataclass(frozen=True)
class DisplaySettings(Section):
    """Operator-side softness display and the E-to-stiffness mapping."""

    TABLE = "display"

    backend: str = spec("sim", choices=("sim", "hid"))
    vendor_id: int = spec(0x1209, lo=0, hi=0xFFFF)
    product_id: int = spec(0x5EF7, lo=0, hi=0xFFFF)
    e_soft_pa: float = spec(5.0e3, lo=0.0, hi=1e12, lo_open=True, doc="E felt as the softest setting")
    e_rigid_pa: float = spec(0.0, lo=0.0, hi=1e13, doc="E at and above which it feels rigid; 0: the estimating "
                             "sensor's resolution limit (Settings.resolution_limit_pa)")
    smoothing_s: float = spec(0.1, lo=0.0, hi=10.0)
    fade_s: float = spec(0.3, lo=0.0, hi=10.0)
    stale_after_s: float = spec(1.0, lo=0.0, hi=60.0, lo_open=True)
    keepalive_s: float = spec(0.2, lo=0.0, hi=60.0, lo_open=True,
                              doc="resend an unchanged command at least this often")

    def _check(self) -> None:
        if self.e_rigid_pa and self.e_rigid_pa <= self.e_soft_pa:
            raise SettingsError(
                f"DisplaySettings.e_rigid_pa = {self.e_rigid_pa}: expected a value above "
                f"e_soft_pa = {self.e_soft_pa}"
            )

    def resolved(self, settings: Settings) -> DisplaySettings:
        """The rigid end set: 0 becomes ``settings``' resolution limit."""
        if self.e_rigid_pa:
            return self
        limit = settings.resolution_limit_pa
        if limit <= self.e_soft_pa:
            raise SettingsError(f"DisplaySettings.e_soft_pa = {self.e_soft_pa}: expected a value below the "
                                f"sensor's resolution limit {limit:.4g} Pa (the display's rigid end)")
        return dataclasses.replace(self, e_rigid_pa=limit)


def display_settings(settings: Settings) -> DisplaySettings:
    """The ``[display]`` table of ``settings``, checked, with its rigid end resolved."""
    return settings.section(DisplaySettings)


def display_range_pa(settings: Settings) -> tuple[float, float]:
    """The display's ``(e_soft_pa, e_rigid_pa)`` under ``settings`` (Pa): what it renders, and the
    range felt errors are clipped to."""
    display = display_settings(settings)
    return display.e_soft_pa, display.e_rigid_pa
