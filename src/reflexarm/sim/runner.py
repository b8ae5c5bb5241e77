"""run_closed_loop: controller <-> plant at the control rate, recorded into a :class:`Trace`."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim.plant import Plant
from reflexarm.sim.scene import Scene
from reflexarm.sim.trace import Trace

__all__ = ["ControllerLike", "TrajectoryLike", "run_closed_loop"]


class ControllerLike(Protocol):
    """What :func:`run_closed_loop` needs from a controller."""

    def reset(self) -> None: ...

    def step(self, measurement: Measurement, reference: Reference) -> Command: ...


class TrajectoryLike(Protocol):
    """What :func:`run_closed_loop` needs from a trajectory (e.g. :class:`JointTrajectory`)."""

    def sample(self, t: float) -> Reference: ...


Callback = Callable[[int, Plant, Measurement, Command], "bool | None"]


def run_closed_loop(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    progress: bool = False,
    callback: Callback | None = None,
    reset_controller: bool = True,
) -> Trace:
    """Run ``controller`` on ``plant`` for ``duration`` seconds from the plant's current state.

    Each control tick k: ``m = plant.measure()``, ``r = trajectory.sample(m.t)``,
    ``cmd = controller.step(m, r)``, the row is recorded, then ``plant.step(cmd.tau)``. The plant is not
    reset (call ``plant.reset(q0)`` first); the controller is (``reset_controller=False`` keeps its state).

    Args:
        plant: the simulated arm.
        controller: any object with ``step(Measurement, Reference) -> Command`` and ``reset()``.
        trajectory: any object with ``sample(t) -> Reference``.
        duration: run length [s]; ``round(duration / plant.control_period)`` ticks are recorded.
        progress: show a tqdm progress bar.
        callback: ``callback(k, plant, measurement, command)`` after each tick's command; returning
            True stops the run (the trace then ends at that tick).
        reset_controller: call ``controller.reset()`` before the first tick.

    Returns:
        The :class:`Trace`; ``meta`` holds the plant's and controller's descriptions.

    Raises:
        Whatever the plant or controller raise mid-run (e.g. :class:`SimulationError` on divergence); the
        ticks recorded so far are attached to the exception as ``.trace`` (a valid :class:`Trace`; the
        failing tick is included when its command was computed).
    """
    try:
        dur = float(duration)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"duration must be a positive number of seconds; got {duration!r}") from e
    if not math.isfinite(dur) or dur <= 0.0:
        raise ConfigError(f"duration must be a positive number of seconds; got {duration!r}")
    if not callable(getattr(controller, "step", None)):
        raise ConfigError(
            f"controller must have a step(measurement, reference) method; got {type(controller).__name__}"
        )
    if not callable(getattr(trajectory, "sample", None)):
        raise ConfigError(f"trajectory must have a sample(t) method; got {type(trajectory).__name__}")
    N = max(1, round(dur / plant.control_period))
    n = plant.n
    rec = _Recorder(N, n)
    meta = _meta(plant, controller, trajectory, dur)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=N, unit="tick", desc="simulating", mininterval=0.5)
    try:
        if reset_controller and callable(getattr(controller, "reset", None)):
            controller.reset()
        qpos, qadr, qvel, vadr = plant._qpos, plant._qadr, plant._qvel, plant._vadr
        observe = [s for s in plant.scenes if type(s).observe is not Scene.observe]
        T, Q, DQ, QM, QD, DQD = rec.t, rec.q, rec.dq, rec.q_meas, rec.q_d, rec.dq_d
        TAU, TAUM, RES, COL, COLD = rec.tau, rec.tau_m, rec.residual, rec.collision, rec.collided
        W, FEE, TEXT, modes, faults = rec.wrench, rec.f_ext_ee, rec.tau_ext, rec.mode, rec.fault
        measure, sample, control, step = plant.measure, trajectory.sample, controller.step, plant.step
        external_torque, ee_force = plant.true_external_torque, plant.ee_contact_force
        for k in range(N):
            m = measure()
            r = sample(m.t)
            cmd = control(m, r)
            T[k] = m.t
            Q[k] = qpos[qadr]
            DQ[k] = qvel[vadr]
            QM[k] = m.q
            QD[k] = r.q_d
            DQD[k] = r.dq_d
            TAU[k] = cmd.tau
            TAUM[k] = m.tau_m
            RES[k] = cmd.residual
            COL[k] = cmd.collision
            if cmd.collided_joints:
                COLD[k, list(cmd.collided_joints)] = True
            modes.append(str(cmd.mode))
            faults.append(str(cmd.fault) if cmd.fault else "")
            W[k] = m.wrench
            external_torque(out=TEXT[k])
            ee_force(out=FEE[k])
            for s in observe:
                rec.put_extras(k, s.observe(plant))
            rec.done = k + 1
            if callback is not None and callback(k, plant, m, cmd):
                break
            step(cmd.tau)
            if bar is not None and (k + 1) % 100 == 0:
                bar.update(100)
    except BaseException as e:
        try:
            e.trace = rec.trace(meta | {"error": f"{type(e).__name__}: {e}"})  # type: ignore[attr-defined]
        except Exception:  # pragma: no cover - never mask the original error
            pass
        raise
    finally:
        if bar is not None:
            bar.update(rec.done - bar.n)
            bar.close()
    return rec.trace(meta)


class _Recorder:
    """Preallocated arrays for N ticks; ``done`` rows are complete."""

    def __init__(self, N: int, n: int) -> None:
        self.N = N
        self.t = np.zeros(N)
        self.q, self.dq, self.q_meas = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n))
        self.q_d, self.dq_d = np.zeros((N, n)), np.zeros((N, n))
        self.tau, self.tau_m, self.residual = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n))
        self.tau_ext = np.zeros((N, n))
        self.collision = np.zeros(N, dtype=bool)
        self.collided = np.zeros((N, n), dtype=bool)
        self.mode: list[str] = []
        self.fault: list[str] = []
        self.wrench = np.zeros((N, 6))
        self.f_ext_ee = np.zeros((N, 3))
        self.extras: dict[str, np.ndarray] = {}
        self.done = 0

    def put_extras(self, k: int, values: dict[str, np.ndarray]) -> None:
        for key, value in values.items():
            arr = self.extras.get(key)
            if arr is None:
                v = np.asarray(value)
                arr = self.extras[key] = np.zeros((self.N, *v.shape), dtype=v.dtype)
            arr[k] = value

    def trace(self, meta: dict[str, Any]) -> Trace:
        d = self.done
        return Trace(
            t=self.t[:d].copy(),
            q=self.q[:d].copy(),
            dq=self.dq[:d].copy(),
            q_meas=self.q_meas[:d].copy(),
            q_d=self.q_d[:d].copy(),
            dq_d=self.dq_d[:d].copy(),
            tau=self.tau[:d].copy(),
            tau_m=self.tau_m[:d].copy(),
            residual=self.residual[:d].copy(),
            collision=self.collision[:d].copy(),
            collided=self.collided[:d].copy(),
            mode=np.array(self.mode[:d], dtype=str),
            fault=np.array(self.fault[:d], dtype=str),
            wrench=self.wrench[:d].copy(),
            f_ext_ee=self.f_ext_ee[:d].copy(),
            tau_ext=self.tau_ext[:d].copy(),
            extras={k: v[:d].copy() for k, v in self.extras.items()},
            meta=meta,
        )


def _describe(obj: Any) -> dict[str, Any]:
    describe = getattr(obj, "describe", None)
    info: dict[str, Any] = {"type": type(obj).__name__}
    if callable(describe):
        try:
            extra = describe()
            if isinstance(extra, dict):
                info.update(extra)
        except Exception as e:  # a description must never stop a run
            info["describe_error"] = repr(e)
    return _jsonable(info)


def _jsonable(value: Any) -> Any:
    """Best-effort conversion to JSON types (numpy arrays/scalars to lists/floats, others to repr)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    try:
        json.dumps(value)
        return value
    except (TypeError, ValueError):
        return repr(value)


def _meta(plant: Plant, controller: Any, trajectory: Any, duration: float) -> dict[str, Any]:
    meta: dict[str, Any] = {"format": "reflexarm.Trace/1", "duration": duration}
    meta.update(_jsonable(plant.describe()))
    meta["controller"] = _describe(controller)
    meta["trajectory"] = _describe(trajectory)
    return meta
