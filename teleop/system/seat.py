"""The demo's simulated operator in the operator's seat: ``teleop demo --operator sim``.

The seat is what ``haptics operate --headless --input sim`` runs, in a thread of the demo: the
operator's loop (:class:`haptics.operator_loop.OperatorLoop`) reads the simulated operator
(:class:`haptics.inputs.sim.SimulatedInput`: a seeded, person-like hand closed on the force it
feels) and drives the robot node leader-follower over the live system's ``command`` endpoint,
sending ``follow`` at the follow rate while its dead-man is held, ``release`` when it is done with
an object and going on to the next. The demo's main thread only listens (:meth:`LiveSystem.operated_grasp
<teleop.system.live_system.LiveSystem.operated_grasp>`); the command publisher is the seat's alone.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING

from haptics.inputs.base import make_input
from haptics.operator_link import ROBOT_TOPICS, OperatorLink
from haptics.operator_loop import OperatorLoop
from teleop.bus.pubsub import Subscriber
from teleop.settings import Settings

if TYPE_CHECKING:
    from teleop.system.live_system import LiveSystem

__all__ = ["SimulatedSeat"]

JOIN_TIMEOUT_S = 5.0

log = logging.getLogger(__name__)


class SimulatedSeat:
    """The simulated operator driving ``system`` for ``grasps`` grasps, in a thread; a context manager.

    Parameters
    ----------
    system : LiveSystem
        Started; its ``commands`` publisher becomes the seat's.
    settings : Settings
        The live system's (``[gripper]`` limits, ``[operator] sim_seed``).
    grasps : int
        Grasps to make; then the operator quits.
    """

    def __init__(self, system: LiveSystem, settings: Settings, *, grasps: int):
        self.device = make_input("sim", settings, grasps=grasps)
        self._system = system
        bus = system.bus  # the live system's endpoints and keys
        self._subscriber = Subscriber.from_settings(bus, [bus.robot_pub, bus.estimate_pub, bus.display_pub],
                                                    (*ROBOT_TOPICS, "estimate", "display"))
        self.link = OperatorLink(publisher=system.commands, subscriber=self._subscriber,
                                 heartbeat_s=settings.bus.heartbeat_s)
        self.loop = OperatorLoop(self.link, self.device, settings)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="simulated-operator", daemon=True)
        self.error: BaseException | None = None

    def _run(self) -> None:
        try:
            self.loop.run(self._stop)
        except BaseException as exc:  # shown by the demo's main thread (check())
            self.error = exc

    def style(self) -> str:
        """How the current (or last) grasp's operator squeezes, in words ("" before the first)."""
        operator = self.device.operator
        return "" if operator is None else operator.style.describe()

    def check(self) -> None:
        """Raise what ended the operator's thread, if something did."""
        if self.error is not None:
            raise self.error

    def __enter__(self) -> SimulatedSeat:
        self.device.connect()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            # Its loop still uses them: a ZeroMQ socket closed under another thread can abort the process.
            # The thread is a daemon: it ends with the demo.
            log.warning("the simulated operator did not stop within %g s: its input, subscriber and command "
                        "publisher are left open", JOIN_TIMEOUT_S)
            self._system.commands = None  # the live system's stop must not close its publisher under it either
            return
        self.device.close()
        self._subscriber.close()
