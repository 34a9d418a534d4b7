"""What the operator's loop (:mod:`haptics.operator_loop`) knows of grasps from the robot's side.

:class:`DiscreteGrasps` tracks the discrete grasps the loop commanded and does not know over; the
functions say whether the robot node can be driven (:func:`unreachable`; why not, when more than one
robot node subscribes to the commands: :func:`crowded`), which grasp the robot runs
(:func:`running`: the one a release or stop names), whether it releases a grasp already
(:func:`releasing`) and whether the grasp shown is over for the operator (:func:`over`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from haptics.operator_link import OperatorView

CROWDED = "driving refused: "  # how the notice of :func:`crowded` begins

__all__ = ["CROWDED", "DiscreteGrasps", "crowded", "over", "releasing", "running", "unreachable"]


class DiscreteGrasps:
    """The discrete grasps commanded and not known over, oldest first.

    A grasp pressed while one runs is refused by the robot, and the one running must stay tracked
    (quit releases it); one refused must go, or ``next`` waits for it forever. A grasp is over once
    the view shows it ended, the watchdog names it, the robot refused to start it
    (``OperatorView.refused_starts``: every refusal, not only the newest notice), a later grasp is
    shown (the robot runs one at a time), or, never seen started, the robot's state names another
    grasp or none ``settle_s`` after it was commanded: a refusal whose notice was lost (a grasp the
    robot takes is named in its state at once, a state comes with every heartbeat, and a node silent
    for longer is heard down).

    Parameters
    ----------
    settle_s : float
        Seconds after which the robot's state has answered a command.
    """

    def __init__(self, settle_s: float) -> None:
        self.settle_s = settle_s
        self._ids: list[str] = []
        self._unstarted: dict[str, float] = {}  # grasp id -> when it was commanded, until seen started

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._ids))

    @property
    def latest(self) -> str | None:
        """The grasp commanded last and not known over."""
        return self._ids[-1] if self._ids else None

    def add(self, grasp_id: str, now_s: float) -> None:
        """``grasp_id`` was commanded at ``now_s``."""
        self._ids.append(grasp_id)
        self._unstarted[grasp_id] = now_s

    def remove(self, grasp_id: str) -> None:
        self._ids.remove(grasp_id)
        self._unstarted.pop(grasp_id, None)

    def clear(self) -> None:
        self._ids, self._unstarted = [], {}

    def update(self, view: OperatorView, over: tuple[str | None, ...], now_s: float) -> None:
        """Forget the grasps ``view`` says are over at ``now_s`` (class docstring); ``over``: ids the
        caller knows ended."""
        robot = view.robot
        for shown in (view.grasp_id, None if robot is None else robot.grasp_id):
            self._unstarted.pop(shown, None)
        if view.grasp_id in self._ids:  # the robot runs one grasp at a time: those before are over
            del self._ids[:self._ids.index(view.grasp_id)]
        gone = {*over, *view.refused_starts}
        if robot is not None:  # its state now names neither: never started
            gone.update(g for g, since in self._unstarted.items() if now_s - since >= self.settle_s)
        self._ids = [g for g in self._ids if g not in gone]
        self._unstarted = {g: since for g, since in self._unstarted.items() if g in self._ids}


def unreachable(view: OperatorView) -> bool:
    """Whether the link hears the robot node down, or not subscribed to the commands: a follow now
    would reach no one, and one held until it is heard would drive it unawares; or more than one
    robot node subscribed (:func:`crowded`): the others would move unwatched, and one held until
    they go would drive the one left unawares."""
    peer = view.peer("robot node")
    return peer is not None and (not peer.alive or peer.subscribed is False or (peer.nodes or 0) > 1)


def crowded(view: OperatorView) -> str:
    """The notice, while more than one robot node subscribes to the commands, that driving is
    refused; "" while at most one does."""
    peer = view.peer("robot node")
    if peer is None or (peer.nodes or 0) < 2:
        return ""
    return (f"{CROWDED}{peer.nodes} robot nodes subscribe to the commands: each would move; stop all but one "
            "(a node on another bus.robot_pub still takes bus.command), then let go of the enable and hold it again")


def running(view: OperatorView) -> str | None:
    """The grasp the robot node runs as ``view`` says: the one its state names (taken, prepared or
    under way), else the one shown loading or loaded; None when neither. While it runs one, the node
    refuses a release naming any other (such as a grasp pressed since and not answered yet)."""
    robot = view.robot
    if robot is not None and robot.grasp_id is not None:
        return robot.grasp_id
    return view.grasp_id if view.phase in ("loading", "loaded") else None


def releasing(robot: Any, grasp_id: str | None) -> bool:
    """Whether the robot's state says it releases grasp ``grasp_id`` already."""
    return robot is not None and robot.grasp_id == grasp_id and robot.mode == "releasing"


def over(view: OperatorView, ended_blind: str | None = None) -> bool:
    """Whether the grasp shown is over for the operator: ended, with its final estimate in unless no
    estimator is alive to send one, or it ended while none was (``ended_blind``: that grasp's id;
    an estimator started since never sends its final)."""
    if view.phase != "ended":
        return False
    final = view.estimate is not None and not view.estimate.provisional
    return final or not view.alive("estimator") or (ended_blind is not None and view.grasp_id == ended_blind)
