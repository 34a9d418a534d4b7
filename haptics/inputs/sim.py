"""The simulated operator as an operator input device: a seeded, person-like hand, closed loop.

Each grasp draws a new :class:`teleop.sim.operator.SimulatedOperator` (its own closing speed,
pauses, partial releases and re-squeezes, peak force), seeded by ``[operator] sim_seed`` and the
grasp's number, so grasp *k* of a seed is the same whatever came before. The operator closes its
loop on what it feels: :meth:`~haptics.inputs.base.OperatorInputDevice.feel` gives it the
robot side's force and finger width (until the first ``feel`` it feels nothing, fingers open).

The first read after ``connect()`` reports the hand idle, the enable released: a person sits
down before pressing the dead-man, and an operator's loop drives only an enable it has seen let go
(:mod:`haptics.operator_loop`). The first grasp's operator starts on the read after it
(``starts_released=False``: on that first read).

Sequence of one grasp, as :meth:`read` reports it (``t_s`` of the operator counts from the
grasp's first read, so a caller may hold off reading until the next object is ready):

1. ``grip = width_to_grip(target width)`` and ``enable`` as the operator commands: it holds the
   enable and squeezes, pauses, backs off and squeezes again, closing on the felt force;
2. one read with buttons ``{"release"}``: the operator is done with the object; from then on it
   lets go of the enable and its grip opens (the caller sends ``release``, the fingers open);
3. once the fingers are open again (``feel`` reports the width), one read with buttons
   ``{"next"}`` (``{"quit"}`` instead after the last of ``grasps`` grasps, when set, and idle
   readings after it); the next read begins the next grasp's operator at its time 0.

``force_n`` is the force the operator feels (on a bilateral display its hand holds that force).
The clock defaults to ``time.monotonic``; a simulation running faster than real time passes its
own (``clock=``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, ClassVar, Self

import numpy as np

from haptics.errors import OperatorInputError
from haptics.inputs.base import OperatorInput, OperatorInputDevice
from haptics.settings import operator_settings
from teleop.operator import width_to_grip
from teleop.settings import Settings

__all__ = ["SimulatedInput"]


class SimulatedInput(OperatorInputDevice):
    """The simulated operator (module notes for the sequence of a grasp).

    Parameters
    ----------
    seed : int
        Seed of the operators drawn (grasp *k* uses ``[seed, k]``).
    max_width_m, max_force_n : float
        The fingers' full opening and the settings' maximum grasp force.
    grasps : int or None
        After this many grasps report ``quit`` instead of ``next`` and stay idle; None: never.
    clock : callable
        Seconds, for the operator's time and :attr:`OperatorInput.t_s`.
    operator_factory : callable
        ``operator_factory(rng, max_width_m=..., max_force_n=...)`` -> an operator with
        ``step(t_s, *, force_n, width_m)`` returning ``target_width_m``, ``enable`` and ``release``,
        and ``done``; default :class:`teleop.sim.operator.SimulatedOperator` (tests pass scripted ones).
    starts_released : bool
        Whether the first read after ``connect()`` reports the hand idle, the enable released (module
        notes); False: the first grasp's operator starts on it.
    """

    name: ClassVar[str] = "sim"
    waits_for_robot: ClassVar[bool] = True

    def __init__(
        self,
        *,
        seed: int = 0,
        max_width_m: float = 0.08,
        max_force_n: float = 30.0,
        grasps: int | None = None,
        clock: Callable[[], float] = time.monotonic,
        operator_factory: Callable[..., Any] | None = None,
        starts_released: bool = True,
    ) -> None:
        super().__init__()
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise OperatorInputError(f"seed = {seed!r}: expected an integer >= 0")
        if grasps is not None and (isinstance(grasps, bool) or not isinstance(grasps, int) or grasps < 1):
            raise OperatorInputError(f"grasps = {grasps!r}: expected an integer >= 1, or None")
        self.seed = seed
        self.max_width_m = max_width_m
        self.max_force_n = max_force_n
        self.grasps = grasps
        self._clock = clock
        self._factory = operator_factory or _simulated_operator
        self.starts_released = bool(starts_released)
        self._restart()

    @classmethod
    def from_settings(cls, settings: Settings, **options: Any) -> Self:
        """Options: ``seed`` (default ``[operator] sim_seed``), ``grasps``, ``clock``,
        ``operator_factory``, ``starts_released``; the width and force come from ``[gripper]``."""
        options.setdefault("seed", operator_settings(settings).sim_seed)
        options.setdefault("max_width_m", settings.gripper.max_width_m)
        options.setdefault("max_force_n", settings.gripper.target_force_n)
        return cls(**options)

    def __repr__(self) -> str:
        return f"<SimulatedInput seed={self.seed} grasps_done={self.grasps_done}>"

    # ------------------------------------------------------------ state

    @property
    def operator(self) -> Any:
        """The current grasp's operator (its ``style`` says how it squeezes); after ``next`` the one
        that just finished, until the next read draws the next; None before the first read."""
        return self._operator

    @property
    def grasps_done(self) -> int:
        """How many grasps have finished (reported ``next`` or ``quit``)."""
        return self._index

    def _restart(self) -> None:
        self._index = 0
        self._operator: Any = None
        self._t0 = 0.0
        self._force_n = 0.0
        self._width_m = float(self.max_width_m)
        self._finished = False
        self._seated = not self.starts_released  # the first read (the hand idle, the enable released) was made

    def _open(self) -> None:
        self._restart()

    def _close(self) -> None:
        pass

    def _feel(self, force_n: float, width_m: float, stiffness: float | None) -> None:  # noqa: ARG002
        self._force_n, self._width_m = force_n, width_m

    # ------------------------------------------------------------ reading

    def _read(self, timeout_s: float) -> OperatorInput:  # noqa: ARG002 - simulated: never waits
        now = self._clock()
        idle = OperatorInput(t_s=now, grip=0.0, enable=False, force_n=self._force_n)
        if self._finished or not self._seated:
            self._seated = True
            return idle
        if self._operator is None or self._operator.done:
            rng = np.random.default_rng([self.seed, self._index])
            self._operator = self._factory(rng, max_width_m=self.max_width_m, max_force_n=self.max_force_n)
            self._t0 = now
        operator = self._operator
        command = operator.step(now - self._t0, force_n=self._force_n, width_m=self._width_m)
        buttons = set()
        if command.release:
            buttons.add("release")
        if operator.done:  # released, and the fingers are open again
            self._index += 1
            self._finished = self.grasps is not None and self._index >= self.grasps
            buttons.add("quit" if self._finished else "next")
        grip = width_to_grip(command.target_width_m, max_width_m=self.max_width_m)
        return OperatorInput(t_s=now, grip=grip, enable=bool(command.enable), force_n=self._force_n,
                             buttons=frozenset(buttons))


def _simulated_operator(rng: np.random.Generator, *, max_width_m: float, max_force_n: float) -> Any:
    from teleop.sim.operator import SimulatedOperator

    return SimulatedOperator(rng, max_width_m=max_width_m, max_force_n=max_force_n)
