"""Run observers: callbacks attached to every closed-loop run started inside a ``with`` block.

A command line run (``reflexarm demo --video``) wants a video and a still of each closed-loop run an
experiment function makes, without every experiment function growing a ``callback`` argument. Inside
``with observing_runs(factory):``, each :func:`~reflexarm.sim.run_closed_loop` (and
:func:`~reflexarm.sim.stream_closed_loop`) calls ``factory(plant)`` once when it starts and calls the
returned callback after every tick, before the run's own ``callback``. Observers only watch: what they
return is ignored, so they never stop a run. The setting is a :class:`contextvars.ContextVar`: it does
not leak into other threads, and processes of a parallel sweep do not see it.

The compiled loop (:func:`~reflexarm.sim.compiled_loop.run_fast`) calls no Python per tick. It still serves
observers that only need a still: an observer whose ``accepts_compiled`` is True gets, after the run, a
:class:`CompiledStill` (the MuJoCo states the loop kept in C++ at the first tick and at the tick of the
largest true external joint torque) through its ``take_compiled(plant, record)`` instead of per-tick calls
(:class:`~reflexarm.sim.video.StillCapture` does). One observer without it (a video) sends the run to the
Python loop: :func:`make_observers` creates the run's observers once, :func:`using_observers` hands those very
observers to the Python run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from reflexarm.signals import Command, Measurement
    from reflexarm.sim.plant import Plant

__all__ = [
    "CompiledStill",
    "ObserverFactory",
    "accepts_compiled",
    "attach_observers",
    "make_observers",
    "observers_active",
    "observing_runs",
    "using_observers",
]

#: ``factory(plant) -> callback(k, plant, measurement, command)``, called once per run.
ObserverFactory = Callable[["Plant"], Callable[[int, "Plant", "Measurement", "Command"], Any]]

_ACTIVE: ContextVar[tuple[ObserverFactory, ...]] = ContextVar("reflexarm_run_observers", default=())
#: Observers already made for the next run of one plant (:func:`using_observers`): (plant id, observers).
_PREMADE: ContextVar[tuple[int, list[Any]] | None] = ContextVar("reflexarm_premade_observers", default=None)


@dataclass(frozen=True)
class CompiledStill:
    """What the compiled loop kept for a still of one run (``reflexarm::StillStates`` in C++).

    Attributes:
        spec: the ``mujoco.mjtState`` mask the states were taken with (``mj_getState``).
        start_tick, start_state: the run's first tick (0-based) and MuJoCo's state then.
        peak_tick, peak_state: the tick of the largest true external joint torque and the state then; None
            when no tick had any (the sum below stayed 0).
        peak2: that largest sum of tau_ext_i^2 over the joints [Nm^2], summed left to right.
        start_time, peak_time: MuJoCo's clock at those ticks [s] (peak_time None without a peak).
        start_command, peak_command: the controller's commands of those ticks, rebuilt from the recorded
            rows (``saturated`` is not recorded by the compiled loop: empty).
    """

    spec: int
    start_tick: int
    start_state: np.ndarray
    start_time: float
    start_command: Command
    peak_tick: int | None
    peak_state: np.ndarray | None
    peak_time: float | None
    peak_command: Command | None
    peak2: float


@contextmanager
def observing_runs(factory: ObserverFactory) -> Iterator[None]:
    """Attach ``factory(plant)``'s callback to every closed-loop run started in the ``with`` block."""
    if not callable(factory):
        from reflexarm.errors import ConfigError

        raise ConfigError(f"an observer factory must be callable factory(plant) -> callback; got {factory!r}")
    token = _ACTIVE.set((*_ACTIVE.get(), factory))
    try:
        yield
    finally:
        _ACTIVE.reset(token)


def observers_active() -> bool:
    """True inside :func:`observing_runs`: a loop that cannot call Python per tick (the compiled loop) must
    hand its recorded states to observers that accept them (:func:`accepts_compiled`) or give way to
    :func:`~reflexarm.sim.run_closed_loop`, or the observers would silently see nothing."""
    return bool(_ACTIVE.get())


def make_observers(plant: Plant) -> list[Any]:
    """The active observers of a run of ``plant`` (each factory called once; empty outside :func:`observing_runs`)."""
    return [f(plant) for f in _ACTIVE.get()]


def accepts_compiled(observer: Any) -> bool:
    """True when ``observer`` can be fed a :class:`CompiledStill` after a compiled run (``accepts_compiled``
    true and a ``take_compiled(plant, record)`` method) instead of a call per tick."""
    return bool(getattr(observer, "accepts_compiled", False)) and callable(getattr(observer, "take_compiled", None))


@contextmanager
def using_observers(plant: Plant, observers: list[Any]) -> Iterator[None]:
    """The next run of ``plant`` started in the block uses these observers (made by :func:`make_observers`)
    instead of calling the factories again; later runs call the factories as usual."""
    token = _PREMADE.set((id(plant), list(observers)))
    try:
        yield
    finally:
        _PREMADE.reset(token)


def attach_observers(
    plant: Plant, callback: Callable[[int, Plant, Measurement, Command], bool | None] | None
) -> Callable[[int, Plant, Measurement, Command], bool | None] | None:
    """The run's ``callback`` preceded by the active observers (``callback`` itself when there are none)."""
    premade = _PREMADE.get()
    if premade is not None and premade[0] == id(plant):
        _PREMADE.set(None)  # used once
        observers = premade[1]
    else:
        observers = make_observers(plant)
    if not observers:
        return callback

    def observed(k: int, p: Plant, m: Measurement, cmd: Command) -> bool | None:
        for observe in observers:
            observe(k, p, m, cmd)
        return None if callback is None else callback(k, p, m, cmd)

    return observed
