"""What the compiled loop (:mod:`reflexarm.sim.compiled_loop`) hands to C++ before a run: the controller's
core parameters, MuJoCo's clock at every tick, the reference sampled at those times, the sensor noise drawn
from the plant's generator and the plant's applied forces (private)."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from reflexarm.errors import SignalError
from reflexarm.sim._plant_sensors import _NOISE_BLOCK
from reflexarm.sim.plant import Plant
from reflexarm.sim.runner import TrajectoryLike
from reflexarm.sim.trajectory import JointTrajectory


def _core_params(controller: Any, core: ModuleType) -> Any:
    """The core's ControllerParams of a (reset) Python Controller: those the Controller configures its own core
    with (``control.controller.core_params``), with the switches it has now."""
    from reflexarm.control.controller import core_params

    p = core_params(controller, core)
    p.kappa_f, p.kappa_eps, p.kappa_ext = (
        int(controller.kappa_f),
        int(controller.kappa_eps),
        int(controller.kappa_ext),
    )
    return p


def _tick_times(plant: Plant, N: int) -> np.ndarray:
    """MuJoCo's clock at each of the next N ticks (it adds ``opt.timestep`` once per physics step)."""
    h = float(plant.model.opt.timestep)
    steps = np.full(N * plant.substeps + 1, h)
    steps[0] = float(plant.data.time)
    # add.accumulate adds left to right, one step at a time: the very sums MuJoCo's clock makes
    return np.add.accumulate(steps)[: N * plant.substeps : plant.substeps].copy()


def _sample_reference(
    trajectory: TrajectoryLike, times: np.ndarray, q_d: np.ndarray, dq_d: np.ndarray, ddq_d: np.ndarray
) -> None:
    """``trajectory.sample`` at every tick time into the (N, n) arrays.

    Two kinds are evaluated as whole arrays (the per-call cost of ``sample`` is ~5 us, a quarter of a
    tick's physics): a :class:`JointTrajectory`, with the operations of its sampling kernel in the same
    order (so the same numbers to the bit), and a trajectory that says it is constant (``is_constant =
    True``, e.g. ``experiments.compensation.HoldReference``: one Reference for every t). Anything else is sampled
    tick by tick (a trajectory returning the same object at the first and last tick may still move between).
    Every sample's q_d, dq_d, ddq_d must have shape (n,) as in the Python loop (a SignalError names the signal and
    the time otherwise; a (1,) reference is not broadcast to every joint).
    """
    if type(trajectory) is JointTrajectory:
        tr: Any = trajectory
        starts, lengths, t_end = tr._starts_arr, tr._lengths_arr, float(tr._t_end)
        i = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, starts.size - 1)
        T = lengths[i]
        x = (times - starts[i]) / T
        x2 = x * x
        s = x2 * x * (10.0 - 15.0 * x + 6.0 * x2)
        ds = 30.0 * x2 * (1.0 - 2.0 * x + x2) / T
        dds = 60.0 * x * (1.0 - 3.0 * x + 2.0 * x2) / (T * T)
        before, after = times <= starts[0], times >= t_end
        i[before], s[before], ds[before], dds[before] = 0, 0.0, 0.0, 0.0
        i[after], s[after], ds[after], dds[after] = starts.size - 1, 1.0, 0.0, 0.0
        d = tr._deltas[i]
        q_d[:] = tr._origins[i] + s[:, None] * d
        dq_d[:] = ds[:, None] * d
        ddq_d[:] = dds[:, None] * d
        return
    n = q_d.shape[1]
    if getattr(trajectory, "is_constant", False) is True:
        first = _checked(trajectory.sample(float(times[0])), n, float(times[0]))
        q_d[:], dq_d[:], ddq_d[:] = first
        return
    sample = trajectory.sample
    for k in range(times.size):
        q_d[k], dq_d[k], ddq_d[k] = _checked(sample(float(times[k])), n, float(times[k]))


def _checked(r: Any, n: int, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q_d, dq_d, ddq_d) of a sampled Reference as (n,) arrays, or a SignalError naming the signal and time."""
    try:
        parts = (np.asarray(r[0]), np.asarray(r[1]), np.asarray(r[2]))
    except (TypeError, IndexError, KeyError) as e:
        raise SignalError("reference", type(r).__name__, "a Reference (q_d, dq_d, ddq_d)", f"at t = {t:g} s") from e
    for name, v in zip(("q_d", "dq_d", "ddq_d"), parts, strict=True):
        if v.shape != (n,):
            raise SignalError(f"reference {name}", f"shape {v.shape}", f"shape ({n},)", f"sampled at t = {t:g} s")
    return parts


def _draw_noise(plant: Plant, N: int) -> np.ndarray | None:
    """The noise rows of the next N measurements, drawn as N calls of ``Plant.measure`` would draw them."""
    if not plant._noisy:
        return None
    out = np.empty((N, plant._dim))
    k = 0
    while k < N:
        if plant._noise_i >= plant._noise_rows.shape[0]:
            plant._noise_rows = plant._rng.uniform(-1.0, 1.0, (_NOISE_BLOCK, plant._dim)) * plant._levels
            plant._noise_i = 0
        take = min(N - k, plant._noise_rows.shape[0] - plant._noise_i)
        out[k : k + take] = plant._noise_rows[plant._noise_i : plant._noise_i + take]
        plant._noise_i += take
        k += take
    return out


def _forces(plant: Plant, skip: set[int] | None = None) -> np.ndarray:
    """The plant's applied forces as rows (body, force, point in the body frame), without the ``skip`` handles."""
    rows = [[f.body, *f.force, *f.point_local] for h, f in plant._forces.items() if not skip or h not in skip]
    return np.array(rows, dtype=float).reshape(-1, 7)
