"""Replay a recorded log through a :class:`~reflexarm.control.Controller` in one call (the C++ core's loop).

:func:`replay` hands the whole log (t, q, dq, tau_m and optionally the wrist wrench) to the controller's C++
core, which runs ``update()`` on every sample in order: the residual, the detection flags and the faults are
those of N calls of :meth:`Controller.step <reflexarm.control.Controller.step>` with the reference held at
the measured position (q_d = q, dq_d = ddq_d = 0), bit for bit, and the controller is left in the state those
calls leave it in (with ``torque=True``; see below otherwise). The residual depends on the measurements only,
not on the reference or the command.

Without ``torque=True`` the core runs the residual-only path (``reflexarm::replayResiduals``): per sample the
input contract, the observer(s) and the detection of ``update()``, without the control law, the torque limits,
the modal damping and the inverse dynamics; the dynamics terms (M(q) dq, C(q, dq)^T dq, g(q), J^T F) come from
one pass over the tree per sample, computed for a block of samples first (on two threads when the machine has
them), then the observers' recursion runs over the block. Its residual, flags, mode and faults equal the full
path's to rounding (~1e-14 Nm: the terms are summed in another order); the controller's observers and clock
are left as N ``step`` calls leave them, its command state (the last command, the modal damping) is not
advanced. The full path runs instead, from the controller's state before the call, when the result would
differ: a detection (the reaction it starts needs the command), a detection already latched in the
controller, or a joint that is not a 1-DoF revolute or prismatic one (:attr:`ReplayResult.full_path_reason` says
which).

The detection pipeline reads a log as ``replay -> events``: :attr:`ReplayResult.events` lists the separate
threshold crossings (runs of samples with some |residual| above the controller's threshold), and
:attr:`ReplayResult.event` is the controller's record of the first detection (its classification and
reaction), as :attr:`Controller.event <reflexarm.control.Controller.event>` gives it after a run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from reflexarm.control.collision.event import CollisionEvent
from reflexarm.errors import ConfigError, DataError

__all__ = ["ReplayEvent", "ReplayResult", "replay"]

#: Samples per thread below which the residual-only path's terms stay on one thread by default (a short log
#: is done in milliseconds either way).
MIN_ROWS_PER_THREAD = 2048

#: Fault texts kept per replay (the first ones; :attr:`ReplayResult.fault_ticks` counts them all).
MAX_FAULT_TEXTS = 16


class ReplayEvent(NamedTuple):
    """One threshold crossing of a replay: consecutive samples with |residual| above the threshold on a joint.

    Attributes:
        start, stop: sample indices [start, stop) of the crossing.
        t_start, t_end: the first and last sample's time [s].
        joints: 0-based joints above their threshold on any of its samples.
        peak: the largest |residual| over its samples and joints [Nm].
    """

    start: int
    stop: int
    t_start: float
    t_end: float
    joints: tuple[int, ...]
    peak: float


@dataclass(frozen=True)
class ReplayResult:
    """What the controller computed on every sample of a log.

    Attributes:
        t: time stamps (N,) [s].
        residual: the detector's residual tau_eps_hat (N, n) [Nm] (:attr:`Command.residual`; a rejected sample
            keeps the previous value, as on the robot).
        collision: (N,) the latched detection (:attr:`Command.collision`).
        over: (N, n) True where the joint's |residual| exceeded its threshold on that sample
            (:attr:`Command.collided_joints`; all False without a threshold).
        mode: (N,) the command's mode code (index into :data:`~reflexarm.control.MODES`).
        fault_code: (N,) 0 for an accepted sample, else the fault code (:attr:`Command.fault_code`).
        tau: the commanded torque (N, n) [Nm] if asked for (``torque=True``), else None.
        fault_ticks: rejected samples; faults: (t, text) of the first :data:`MAX_FAULT_TEXTS` of them.
        events: the separate threshold crossings, in time order (:class:`ReplayEvent`).
        event: the controller's record of the first detection (:class:`CollisionEvent`) or None.
        residual_only: True if the residual-only path ran (no ``torque``; module docstring).
        full_path_reason: why the full path ran ("" when the residual-only path did).
    """

    t: np.ndarray
    residual: np.ndarray
    collision: np.ndarray
    over: np.ndarray
    mode: np.ndarray
    fault_code: np.ndarray
    tau: np.ndarray | None
    fault_ticks: int
    faults: tuple[tuple[float, str], ...]
    events: tuple[ReplayEvent, ...]
    event: CollisionEvent | None
    residual_only: bool = False
    full_path_reason: str = ""

    @property
    def modes(self) -> np.ndarray:
        """The mode names (N,) (:attr:`Command.mode`)."""
        from reflexarm.control.controller import MODES

        return np.asarray(MODES)[self.mode]


def replay(
    controller: Any,
    t: npt.ArrayLike,
    q: npt.ArrayLike,
    dq: npt.ArrayLike,
    tau: npt.ArrayLike,
    wrench: npt.ArrayLike | None = None,
    *,
    gravity: npt.ArrayLike | None = None,
    torque: bool = False,
    threads: int | None = None,
) -> ReplayResult:
    """Run a whole log through ``controller`` in one call of its C++ core (module docstring).

    Args:
        controller: a :class:`~reflexarm.control.Controller`; it goes on from its current state (call
            ``reset()`` first for a fresh start) and is left where N calls of ``step`` would leave it.
        t: time stamps (N,) [s], finite and strictly increasing.
        q, dq, tau: measured positions [rad], velocities [rad/s] and joint torques [Nm], (N, n) each. A
            non-finite or implausible value is a rejected sample (a fault, as in ``step``), not an error.
        wrench: the wrist wrench (N, 6) [N, Nm] or None (zero, as a log without a sensor).
        gravity: the measured gravity (3,) [m/s^2]; default the controller's model gravity.
        torque: also keep the commanded torque (another N x n array): the full path, every sample a whole
            ``update()``; without it the residual-only path (module docstring).
        threads: threads of the residual-only path's dynamics terms, 1 or 2; default 2 when the machine has
            two cores and the log has at least :data:`MIN_ROWS_PER_THREAD` samples per thread, else 1.

    Raises:
        ConfigError: ``controller`` is not a reflexarm Controller; ``threads`` is not 1, 2 or None.
        DataError: an array of another shape or not of real numbers, no samples, or time stamps that are not
            finite and strictly increasing (the message names the array and the first bad sample).
    """
    from reflexarm.control.controller import Controller

    if not isinstance(controller, Controller):
        raise ConfigError(f"replay needs a reflexarm Controller; got {type(controller).__name__}")
    n = controller.n
    tt = _as_real(t, "t", None)
    N = tt.shape[0] if tt.ndim == 1 else -1
    if tt.ndim != 1 or N == 0:
        raise DataError(f"t must have shape (N,) with N >= 1; got {tt.shape}", column="t", value=tt.shape)
    _check_time(tt)
    arrays = [_as_real(a, name, (N, n)) for a, name in ((q, "q"), (dq, "dq"), (tau, "tau"))]
    w = None if wrench is None else _as_real(wrench, "wrench", (N, 6))
    g = np.asarray(controller.robot.gravity if gravity is None else gravity, dtype=float)
    if g.shape != (3,):
        raise DataError(f"gravity must have shape (3,); got {g.shape}", column="gravity", value=g.shape)
    residual, over = np.empty((N, n)), np.zeros((N, n), dtype=np.uint8)
    collision, mode, status = np.zeros(N, np.uint8), np.zeros(N, np.int8), np.zeros(N, np.int32)
    tau_out = np.empty((N, n)) if torque else None
    if threads is None:
        threads = 2 if (os.cpu_count() or 1) >= 2 and N >= 2 * MIN_ROWS_PER_THREAD else 1
    elif threads not in (1, 2):
        raise ConfigError(f"threads must be 1, 2 or None; got {threads!r}")
    core = controller._core
    rejected, texts, residual_only, reason = core.replay(
        tt, *arrays, w, np.ascontiguousarray(g), residual, tau_out, over, collision, mode, status, MAX_FAULT_TEXTS,
        residual_only=True, threads=threads,  # the core runs the full path when tau is asked for (and says so)
    )  # fmt: skip
    _sync_detector(controller, tt, over)
    over_b = over.view(bool)
    return ReplayResult(
        t=tt,
        residual=residual,
        collision=collision.view(bool),
        over=over_b,
        mode=mode,
        fault_code=np.minimum(status, 0),
        tau=tau_out,
        fault_ticks=int(rejected),
        faults=tuple((float(tt[k]), str(text)) for k, text in texts),
        events=_events(tt, residual, over_b),
        event=controller.event,
        residual_only=bool(residual_only),
        full_path_reason=str(reason),
    )


def _as_real(value: npt.ArrayLike, name: str, shape: tuple[int, int] | None) -> np.ndarray:
    """``value`` as a C-contiguous float64 array (one copy at most), or a DataError naming it."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "iuf":
            raise TypeError(f"dtype {arr.dtype}")
        out = np.ascontiguousarray(arr, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise DataError(f"{name} must be an array of real numbers; got {e}", column=name) from e
    if shape is not None and out.shape != shape:
        raise DataError(
            f"{name} must have shape {shape} (N samples x n joints); got {out.shape}",
            column=name,
            value=out.shape,
            expected=shape,
        )
    return out


def _check_time(t: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        k = int(bad[0])
        raise DataError(f"t must be finite; t[{k}] = {float(t[k])!r}", column="t", row=k, value=float(t[k]))
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        k = int(back[0]) + 1
        raise DataError(
            f"t must be strictly increasing; t[{k}] = {float(t[k])!r} <= t[{k - 1}] = {float(t[k - 1])!r}",
            column="t",
            row=k,
            value=float(t[k]),
        )


def _sync_detector(controller: Any, t: np.ndarray, over: np.ndarray) -> None:
    """The Python side of the controller as N ``step`` calls leave it: the detector's first crossing, the mode."""
    if controller.detector is not None and not controller.detector.detected:
        rows = np.flatnonzero(over.any(axis=1))
        if rows.size:
            k = int(rows[0])
            controller.detector.record(tuple(np.flatnonzero(over[k]).tolist()), float(t[k]))
    controller._mode = controller._core.mode


def _events(t: np.ndarray, residual: np.ndarray, over: np.ndarray) -> tuple[ReplayEvent, ...]:
    """Runs of samples with some joint over its threshold."""
    anyo = over.any(axis=1)
    if not anyo.any():
        return ()
    edges = np.diff(np.r_[0, anyo.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = []
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        joints = tuple(np.flatnonzero(over[a:b].any(axis=0)).tolist())
        peak = float(np.max(np.abs(residual[a:b][:, list(joints)])))
        out.append(ReplayEvent(a, b, float(t[a]), float(t[b - 1]), joints, peak))
    return tuple(out)
