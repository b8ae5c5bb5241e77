"""Run observers: callbacks attached to every closed-loop run started inside a ``with`` block.

A command line run (``reflexarm demo --video``) wants a video and a still of each closed-loop run an
experiment function makes, without every experiment function growing a ``callback`` argument. Inside
``with observing_runs(factory):``, each :func:`~reflexarm.sim.run_closed_loop` (and
:func:`~reflexarm.sim.stream_closed_loop`) calls ``factory(plant)`` once when it starts and calls the
returned callback after every tick, before the run's own ``callback``. Observers only watch: what they
return is ignored, so they never stop a run. The setting is a :class:`contextvars.ContextVar`: it does
not leak into other threads, and processes of a parallel sweep do not see it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from reflexarm.signals import Command, Measurement
    from reflexarm.sim.plant import Plant

__all__ = ["ObserverFactory", "attach_observers", "observers_active", "observing_runs"]

#: ``factory(plant) -> callback(k, plant, measurement, command)``, called once per run.
ObserverFactory = Callable[["Plant"], Callable[[int, "Plant", "Measurement", "Command"], Any]]

_ACTIVE: ContextVar[tuple[ObserverFactory, ...]] = ContextVar("reflexarm_run_observers", default=())


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
    give way to :func:`~reflexarm.sim.run_closed_loop`, or the observers would silently see nothing."""
    return bool(_ACTIVE.get())


def attach_observers(
    plant: Plant, callback: Callable[[int, Plant, Measurement, Command], bool | None] | None
) -> Callable[[int, Plant, Measurement, Command], bool | None] | None:
    """The run's ``callback`` preceded by the active observers (``callback`` itself when there are none)."""
    factories = _ACTIVE.get()
    if not factories:
        return callback
    observers = [f(plant) for f in factories]

    def observed(k: int, p: Plant, m: Measurement, cmd: Command) -> bool | None:
        for observe in observers:
            observe(k, p, m, cmd)
        return None if callback is None else callback(k, p, m, cmd)

    return observed
