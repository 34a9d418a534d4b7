"""What the operator's loop (:class:`~haptics.operator_loop.OperatorLoop`) needs of its input device
and link (:class:`InputDevice`, :class:`Link`), and what it shows a user interface (:class:`LoopStatus`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from haptics.operator_link import OperatorView
from teleop.bus.messages import LabelBody

__all__ = ["InputDevice", "Link", "LoopStatus"]


class InputDevice(Protocol):
    """What the loop needs of an operator input device (:mod:`haptics.inputs`)."""

    waits_for_robot: bool

    def connect(self) -> Any: ...

    def read(self, *, timeout_s: float) -> Any: ...

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None) -> None: ...


class Link(Protocol):
    """What the loop needs of a link: :class:`~haptics.operator_link.OperatorLink` or a test's fake."""

    view: OperatorView

    def poll(self, timeout_s: float = 0.0) -> int: ...

    def follow(self, target_width_m: float, *, enable: bool, grasp_id: str | None = None) -> None: ...

    def start_grasp(self, *, target_force_n: float, grasp_id: str | None = None) -> None: ...

    def stop(self, grasp_id: str | None = None) -> None: ...

    def release(self, grasp_id: str | None = None) -> None: ...

    def clear(self) -> None: ...

    def label(self, grasp_id: str, object_name: str, *, modulus_pa: float | None = None, source: str,
              detail: str = "") -> None: ...


@dataclass(frozen=True)
class LoopStatus:
    """The loop's state for a user interface (a frozen snapshot, safe to read from any thread)."""

    view: OperatorView
    grip: float = 0.0
    enable: bool = False  # the enable as the loop takes it: held and not suspended
    held: bool = False  # the device's enable as read (a toggle's state)
    suspended: bool = False  # the enable is held but drives nothing until it is let go and held again
    operator_force_n: float | None = None  # the operator's grip force, where the device measures it
    target_width_m: float | None = None
    mode: str = "idle"  # "idle", "follow" (driving with enable), "discrete" (a commanded grasp under way)
    grasp_id: str | None = None  # the grasp the loop drives or commanded last
    force_n: float = 0.0  # the discrete grasp's force
    last_action: str = ""  # what the operator did last, in words
    problem: str = ""  # the last thing that went wrong (a send or read that failed), in words
    follows_sent: int = 0
    commands_sent: int = 0
    quit: bool = False
    log: tuple[str, ...] = field(default_factory=tuple)
    label_grasp_id: str | None = None  # the grasp a label would name now: the current one, else the last
    labels: Mapping[str, LabelBody] = field(default_factory=dict)  # grasp id -> the label body sent, this session
    last_ended: OperatorView | None = None  # the view of the last grasp "next" cleared, as it was then
