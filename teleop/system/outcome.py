"""What one grasp of the live system gave: the operator's view of it (:class:`GraspOutcome`) and the
services' JSON-lines reports it is completed from (:class:`ReportReader`)."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from estimator.evaluation.metrics import felt_log10_error, felt_log10_offset, felt_within
from estimator.settings import EstimatorSettings
from haptics.errors import MappingError
from haptics.mapping import EstimateUpdate, Percept, map_estimate, modulus_from_fraction
from teleop.bus.messages import EstimateBody, RobotNoticeBody
from teleop.catalogue import ObjectSpec

__all__ = ["GraspOutcome", "ReportReader", "display_felt_pa"]

log = logging.getLogger(__name__)


def display_felt_pa(e_pa: float | None, *, unknown: bool, e_soft_pa: float | None) -> float | None:
    """The modulus a ``display`` message renders, as the operator feels it: its ``E_pa``; the display's
    soft end ``e_soft_pa`` when it has none (stiffness 0: free); None when it showed the modulus unknown."""
    return None if unknown else (e_pa if e_pa is not None else e_soft_pa)


class ReportReader:
    """Reads a JSON-lines report another process appends to, line by complete line; a line that is
    no JSON object (torn by a writer killed mid-line) is logged and skipped."""

    def __init__(self, path: Path):
        self.path = path
        self._offset = 0
        self._lines = 0  # complete lines read, to name a broken one
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
        new = []
        for line in complete.splitlines():
            self._lines += 1
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except ValueError:  # a line torn by a killed writer, not UTF-8
                record = None
            if isinstance(record, dict):
                new.append(record)
            else:
                log.warning("%s line %d: not a JSON object, skipped", self.path, self._lines)
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

    grasp_id: str | None  # None until the grasp an operator makes has started
    obj: ObjectSpec
    style: str = "script"  # "script": the paper's commanded grasp; "operator": a person (or the simulated one) drove it
    operator_style: str = ""  # how the simulated operator squeezed, in words
    started: bool = False
    robot_ended: bool = False
    estimator_ended: bool = False
    estimates: int = 0
    latest: EstimateBody | None = None  # the newest estimate
    final: EstimateBody | None = None  # the final estimate
    estimator_report: dict[str, Any] | None = None
    renderer_report: dict[str, Any] | None = None
    display_range: tuple[float, float] | None = None
    # Convergence, from the grasp's own bus messages: when its force first reached contact_force_n
    # (load-cell capture time) and each display report written for it (write time, E_pa or None).
    contact_force_n: float = field(default_factory=lambda: EstimatorSettings().contact_force_n)
    t_contact_s: float | None = None
    display_track: list[tuple[float, float | None]] = field(default_factory=list)
    # The robot_notice that ended the grasp before it ran its course (its ended_grasp), None otherwise.
    ended_by: RobotNoticeBody | None = None

    def observe(self, message: Any) -> None:
        """Note a ``force`` or ``display`` message of this grasp (the convergence figures), or a
        ``robot_notice`` naming it that ended it (:attr:`ended_by`: the first such)."""
        body = message.fields
        if message.type == "robot_notice":
            ended = body.ended_grasp()
            if self.ended_by is None and ended is not None and ended == self.grasp_id:
                self.ended_by = body
        elif message.type == "force" and self.t_contact_s is None:
            reached = np.flatnonzero(np.asarray(body.value_n) >= self.contact_force_n)
            if reached.size:
                self.t_contact_s = float(body.t_s[reached[0]])
        elif message.type == "display" and body.phase == "active":  # not the fade after the grasp
            soft_end = self.display_range[0] if self.display_range else None
            self.display_track.append((message.t_capture_s, display_felt_pa(body.E_pa, unknown=body.unknown,
                                                                            e_soft_pa=soft_end)))

    @property
    def done(self) -> bool:
        return self.robot_ended and self.estimator_ended

    @property
    def e_final_pa(self) -> float | None:
        return None if self.final is None else self.final.E_pa

    @property
    def state(self) -> str:
        return "none" if self.final is None else self.final.state

    @property
    def interval_pa(self) -> list[float | None] | None:
        """The final estimate's interval [low, high] (None: an open side); None without a final."""
        if self.final is None:
            return None
        low, high = self.final.interval_pa
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
            update = EstimateUpdate(self.final.E_pa, tuple(self.interval_pa), self.final.state)
            return map_estimate(update, e_soft_pa=soft, e_rigid_pa=rigid)
        except MappingError:
            return None

    @property
    def display_fraction(self) -> float | None:
        """Fraction of the display's range rendered for the final estimate: 0 free, 1 rigid; None without
        a rendering, or when the display showed the modulus as unknown (it goes free, placing the object
        nowhere: not the softest)."""
        rendered = self.rendered
        return None if rendered is None or rendered.unknown else rendered.stiffness

    @property
    def display_e_pa(self) -> float | None:
        """The modulus the rendered fraction stands for on the display's (logarithmic) scale."""
        fraction = self.display_fraction
        if fraction is None or self.display_range is None:
            return None
        soft, rigid = self.display_range
        return modulus_from_fraction(fraction, e_soft_pa=soft, e_rigid_pa=rigid)

    @property
    def log10_offset(self) -> float | None:
        """Decades from the label to the final estimate, signed (negative: estimated softer than it is)."""
        e = self.e_final_pa
        return None if e is None else math.log10(e / self.obj.modulus_pa)

    @property
    def felt_log10_offset(self) -> float | None:
        """Decades from the label clipped to the display's range to what the display rendered (a rigid
        object rendered rigid is exact; negative: felt softer than it is); None without a rendering or a
        range, or when the display showed the modulus as unknown (a refusal, or an interval over its whole range)."""
        felt = self.display_e_pa
        if felt is None:
            return None
        return felt_log10_offset(felt, self.obj.modulus_pa, display_range_pa=self.display_range)

    @property
    def felt_log10_error(self) -> float | None:
        """The size of :attr:`felt_log10_offset`."""
        offset = self.felt_log10_offset
        return None if offset is None else abs(offset)

    @property
    def t_felt_within_2x_s(self) -> float | None:
        """Time (s) from contact until the display stays within a factor 2 of the label clipped to its
        range, for every report from then to the grasp's last; None when it never settles there (or
        without contact, reports or a range). Load cell and display share the host's monotonic clock."""
        if self.t_contact_s is None or not self.display_track or self.display_range is None:
            return None
        settled = None
        for t_s, e_pa in self.display_track:
            if e_pa is None or not felt_within(felt_log10_error(e_pa, self.obj.modulus_pa,
                                                                display_range_pa=self.display_range)):
                settled = None
            elif settled is None:
                settled = t_s
        return None if settled is None else max(0.0, settled - self.t_contact_s)

    @property
    def model(self) -> str | None:
        """The id of the learned model that made the final estimate (None: an analytical one, or none)."""
        return None if self.final is None else self.final.model

    @property
    def t_first_estimate_s(self) -> float | None:
        return None if self.estimator_report is None else self.estimator_report.get("time_to_first_estimate_s")

    @property
    def latency_ms(self) -> float | None:
        """From the last loading frame's capture to the display report of the final (renderer report);
        None for an operator's grasp, whose final waits seconds after the peak for the hand to let go
        (its provisional estimates follow the squeeze: see :attr:`t_felt_within_2x_s`)."""
        if self.renderer_report is None or self.style != "script":
            return None
        return self.renderer_report.get("latency_ms")

    def to_json(self) -> dict[str, Any]:
        """The grasp as ``teleop demo --json`` gives it. What the display rendered: ``display_unknown``
        (no modulus shown: the display goes free, and ``display_fraction`` is null), ``display_rigid``
        and ``display_fraction`` (0 free, 1 rigid); all null without a rendering. ``ended_by``: the
        ``event``, ``action`` and ``reason`` of the robot_notice that cut the grasp short (the
        watchdog's, a failed gripper command's), null when it ran its course."""
        rendered = self.rendered
        notice = self.ended_by
        return {"object": self.obj.name, "style": self.style, "operator_style": self.operator_style,
                "E_true_pa": self.obj.modulus_pa, "E_final_pa": self.e_final_pa,
                "log10_offset": self.log10_offset, "t_first_estimate_s": self.t_first_estimate_s,
                "latency_ms": self.latency_ms, "state": self.state, "interval_pa": self.interval_pa,
                "display_fraction": self.display_fraction,
                "display_rigid": None if rendered is None else rendered.rigid,
                "display_unknown": None if rendered is None else rendered.unknown,
                "felt_log10_offset": self.felt_log10_offset, "felt_log10_error": self.felt_log10_error,
                "t_felt_within_2x_s": self.t_felt_within_2x_s, "model": self.model,
                "ended_by": None if notice is None else {"event": notice.event, "action": notice.action,
                                                         "reason": notice.reason}}
