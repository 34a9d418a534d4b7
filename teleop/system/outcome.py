"""What one grasp of the live system gave: the operator's view of it (:class:`GraspOutcome`) and the
services' JSON-lines reports it is completed from (:class:`ReportReader`)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptics.errors import MappingError
from haptics.mapping import EstimateUpdate, Percept, map_estimate, modulus_from_fraction
from teleop.catalogue import ObjectSpec

__all__ = ["GraspOutcome", "ReportReader"]


class ReportReader:
    """Reads a JSON-lines report another process appends to, line by complete line."""

    def __init__(self, path: Path):
        self.path = path
        self._offset = 0
        self.records: list[dict[str, Any]] = []

    def poll(self) -> list[dict[str, Any]]:
        """Records appended since the last call."""
        try:
            with self.path.open("rb") as fh:
                fh.seek(self._offset)
                data = fh.read()
        except FileNotFoundError:
            return []
        complete = data[: data.rfind(b"\n") + 1]
        self._offset += len(complete)
        new = [json.loads(line) for line in complete.decode("utf-8").splitlines() if line.strip()]
        self.records.extend(new)
        return new

    def find(self, grasp_id: str, *, timeout_s: float) -> dict[str, Any] | None:
        """The record of ``grasp_id``, waiting up to ``timeout_s`` for it to be written."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.poll()
            found = next((r for r in self.records if r.get("grasp_id") == grasp_id), None)
            if found is not None or time.monotonic() >= deadline:
                return found
            time.sleep(0.02)


@dataclass
class GraspOutcome:
    """One grasp of the live system as the operator saw it, with the services' reports.

    ``display_range`` is the display's (e_soft_pa, e_rigid_pa) from the settings: it turns the rendered
    fraction into a modulus, and renders the final estimate when the renderer reported none.
    """

    grasp_id: str
    obj: ObjectSpec
    started: bool = False
    robot_ended: bool = False
    estimator_ended: bool = False
    estimates: int = 0
    latest: dict[str, Any] | None = None  # body of the newest estimate
    final: dict[str, Any] | None = None  # body of the final estimate
    estimator_report: dict[str, Any] | None = None
    renderer_report: dict[str, Any] | None = None
    display_range: tuple[float, float] | None = None

    @property
    def done(self) -> bool:
        return self.robot_ended and self.estimator_ended

    @property
    def e_final_pa(self) -> float | None:
        return None if self.final is None else self.final["E_pa"]

    @property
    def state(self) -> str:
        return "none" if self.final is None else self.final["state"]

    @property
    def interval_pa(self) -> list[float | None] | None:
        """The final estimate's interval [low, high] (None: an open side); None without a final."""
        if self.final is None:
            return None
        low, high = self.final.get("interval_pa") or (None, None)
        return [low, high]

    @property
    def rendered(self) -> Percept | None:
        """What the display rendered for the final estimate: as the renderer reported it, or else the
        final estimate mapped onto ``display_range``; None without a final estimate."""
        if self.final is None:
            return None
        report = self.renderer_report or {}
        if report.get("display_fraction") is not None:
            return Percept(stiffness=report["display_fraction"], rigid=bool(report.get("rigid")),
                           unknown=bool(report.get("unknown")))
        if self.display_range is None:
            return None
        soft, rigid = self.display_range
        try:
            update = EstimateUpdate(self.final["E_pa"], tuple(self.interval_pa), self.final["state"])
            return map_estimate(update, e_soft_pa=soft, e_rigid_pa=rigid)
        except MappingError:
            return None

    @property
    def display_fraction(self) -> float | None:
        """Fraction of the display's range rendered for the final estimate: 0 free, 1 rigid."""
        return None if self.rendered is None else self.rendered.stiffness

    @property
    def display_e_pa(self) -> float | None:
        """The modulus the rendered fraction stands for on the display's (logarithmic) scale."""
        fraction = self.display_fraction
        if fraction is None or self.display_range is None:
            return None
        soft, rigid = self.display_range
        return modulus_from_fraction(fraction, e_soft_pa=soft, e_rigid_pa=rigid)

    @property
    def log10_error(self) -> float | None:
        e = self.e_final_pa
        return None if e is None else math.log10(e / self.obj.modulus_pa)

    @property
    def t_first_estimate_s(self) -> float | None:
        return None if self.estimator_report is None else self.estimator_report.get("time_to_first_estimate_s")

    @property
    def latency_ms(self) -> float | None:
        return None if self.renderer_report is None else self.renderer_report.get("latency_ms")

    def to_json(self) -> dict[str, Any]:
        return {"object": self.obj.name, "E_true_pa": self.obj.modulus_pa, "E_final_pa": self.e_final_pa,
                "log10_error": self.log10_error, "t_first_estimate_s": self.t_first_estimate_s,
                "latency_ms": self.latency_ms, "state": self.state, "interval_pa": self.interval_pa,
                "display_fraction": self.display_fraction}
