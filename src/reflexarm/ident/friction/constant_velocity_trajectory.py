"""The reference of the single-joint friction experiments (Sec. II-D-2, Fig. 4): one joint moves at a set
of constant velocities, in positive and negative direction, with trapezoidal ramps between rest and
constant speed, while the others hold still.

* :func:`plan_friction_experiment` builds the reference for one joint (:class:`ConstantVelocityTrajectory`,
  with ``sample(t)``), inside the joint's position limits and velocity limit.

The measured runs are turned into a friction law by :mod:`reflexarm.ident.friction.joint_friction`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Reference

__all__ = ["ConstantVelocityTrajectory", "plan_friction_experiment"]

#: Default speeds of the single-joint experiments [rad/s], each run in both directions.
DEFAULT_SPEEDS = (0.1, 0.2, 0.35, 0.5, 0.75, 1.0)
#: Default acceleration of the ramps between rest and constant speed [rad/s^2].
DEFAULT_RAMP_ACCELERATION = 3.0
#: Shortest constant-speed interval planned [s].
MIN_CONSTANT_TIME = 0.4


@dataclass(frozen=True)
class ConstantVelocityTrajectory:
    """Reference of single-joint constant-velocity runs: rest, ramp, constant speed, ramp, rest, ...

    Attributes:
        joint: index (0-based) of the moving joint.
        hold: the configuration of all joints at t = 0 (the others stay there) [rad].
        segments: one row per move, ``(t_start, q_start, q_end, speed)``: the moving joint goes from
            ``q_start`` to ``q_end`` with trapezoidal velocity (``acceleration`` ramps, |dq| = ``speed``).
        acceleration: ramp acceleration [rad/s^2].
        dwell: rest between moves [s].
    """

    joint: int
    hold: np.ndarray
    segments: np.ndarray
    acceleration: float
    dwell: float

    @property
    def n(self) -> int:
        return int(self.hold.size)

    @property
    def duration(self) -> float:
        """End of the last move plus a dwell [s]."""
        t0, qa, qb, v = self.segments[-1]
        return float(t0 + _move_time(abs(qb - qa), v, self.acceleration) + self.dwell)

    @property
    def start(self) -> np.ndarray:
        """q at t = 0 [rad]."""
        return self.hold.copy()

    @property
    def windows(self) -> np.ndarray:
        """Planned constant-speed intervals, one row per move: ``(t_begin, t_end, velocity)``."""
        out = []
        for t0, qa, qb, v in self.segments:
            ramp = v / self.acceleration
            dur = _move_time(abs(qb - qa), v, self.acceleration)
            out.append((t0 + ramp, t0 + dur - ramp, np.sign(qb - qa) * v))
        return np.array(out)

    def position_window(self, settle: float = 0.0) -> tuple[float, float]:
        """The range of the moving joint that every move crosses at constant, settled speed [rad].

        Averaging every interval over the same positions makes an error of the model's rigid-body torque
        (gravity above all) the same for every speed and direction, so it cannot leak into d_v; a fitted
        offset then absorbs it completely.
        """
        lo = max(min(qa, qb) for _, qa, qb, _ in self.segments)
        hi = min(max(qa, qb) for _, qa, qb, _ in self.segments)
        d = max(v * v / (2 * self.acceleration) + settle * v for *_, v in self.segments)
        if hi - lo <= 2 * d:
            raise ConfigError(
                f"the travel {hi - lo:.3g} rad is too short for a common constant-speed window at the fastest "
                f"speed (needs more than {2 * d:.3g} rad)"
            )
        return float(lo + d), float(hi - d)

    def evaluate(self, t: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, ddq), each (N, n), at times ``t`` [s]."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        N = tt.size
        q = np.tile(self.hold, (N, 1))
        dq = np.zeros((N, self.n))
        ddq = np.zeros((N, self.n))
        j = self.joint
        a = self.acceleration
        qj = np.full(N, self.segments[0, 1])
        for t0, qa, qb, v in self.segments:
            D = abs(qb - qa)
            s = np.sign(qb - qa)
            T = _move_time(D, v, a)
            tr = v / a
            tau = tt - t0
            before = tau < 0
            after = tau >= T
            inside = ~before & ~after
            # position along the move (trapezoid): accelerate, cruise, decelerate
            x = np.where(
                tau < tr,
                0.5 * a * tau**2,
                np.where(tau < T - tr, 0.5 * a * tr**2 + v * (tau - tr), D - 0.5 * a * (T - tau) ** 2),
            )
            vel = np.where(tau < tr, a * tau, np.where(tau < T - tr, v, a * (T - tau)))
            acc = np.where(tau < tr, a, np.where(tau < T - tr, 0.0, -a))
            qj = np.where(inside, qa + s * x, np.where(after, qb, qj))
            dq[inside, j] = s * vel[inside]
            ddq[inside, j] = s * acc[inside]
        q[:, j] = qj
        return q, dq, ddq

    def sample(self, t: float) -> Reference:
        """The reference at time ``t`` [s] (the interface of the closed-loop runner; scalar fast path)."""
        seg = self.segments
        k = int(np.searchsorted(seg[:, 0], t, side="right")) - 1
        q = self.hold.copy()
        dq = np.zeros(self.n)
        ddq = np.zeros(self.n)
        j = self.joint
        if k < 0:
            q[j] = seg[0, 1]
            return Reference(q, dq, ddq)
        t0, qa, qb, v = seg[k]
        a = self.acceleration
        D = abs(qb - qa)
        s = 1.0 if qb >= qa else -1.0
        T = _move_time(D, v, a)
        tr = v / a
        tau = t - t0
        if tau >= T:
            q[j] = qb
        elif tau < tr:
            q[j], dq[j], ddq[j] = qa + s * 0.5 * a * tau * tau, s * a * tau, s * a
        elif tau < T - tr:
            q[j], dq[j] = qa + s * (0.5 * a * tr * tr + v * (tau - tr)), s * v
        else:
            q[j], dq[j], ddq[j] = qa + s * (D - 0.5 * a * (T - tau) ** 2), s * a * (T - tau), -s * a
        return Reference(q, dq, ddq)


def _move_time(distance: float, speed: float, acceleration: float) -> float:
    """Duration of a trapezoidal move that reaches ``speed`` (distance >= speed^2 / acceleration)."""
    return float(distance / speed + speed / acceleration)


def plan_friction_experiment(
    robot: RobotModel,
    joint: int,
    *,
    speeds: Sequence[float] | None = None,
    hold: npt.ArrayLike | None = None,
    margin: float = 0.15,
    max_travel: float = 1.5,
    acceleration: float = DEFAULT_RAMP_ACCELERATION,
    dwell: float = 0.5,
) -> ConstantVelocityTrajectory:
    """Plan constant-velocity runs of one joint: each speed once in each direction.

    Args:
        robot: the arm (limits).
        joint: 0-based index of the joint to move.
        speeds: the speeds [rad/s] (default :data:`DEFAULT_SPEEDS`); those above 90 % of the joint's
            velocity limit are dropped, and so are those that leave less than :data:`MIN_CONSTANT_TIME`
            of constant speed in the travel.
        hold: configuration of the other joints (default: the robot's home, clipped into the limits).
        margin: distance kept from the moving joint's position limits [rad].
        max_travel: longest travel of a move [rad].
        acceleration: ramp acceleration [rad/s^2].
        dwell: rest between moves [s].

    Raises:
        ConfigError: bad joint index, no usable range or no usable speed (the message says why).
    """
    n = robot.n
    if not (isinstance(joint, (int, np.integer)) and 0 <= joint < n):
        raise ConfigError(f"joint must be an index 0..{n - 1}; got {joint!r}")
    lo, hi = robot.lower_limit[joint], robot.upper_limit[joint]
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi - lo > 2 * np.pi:
        lo, hi = -np.pi, np.pi
    lo, hi = lo + margin, hi - margin
    if hi <= lo:
        raise ConfigError(f"joint {joint + 1} ({robot.joint_names[joint]}) has no range left with margin {margin} rad")
    q_hold = robot.home.copy() if hold is None else np.asarray(hold, dtype=float).copy()
    q_hold = np.clip(q_hold, robot.lower_limit, robot.upper_limit)
    centre = float(np.clip(q_hold[joint], lo, hi))
    travel = min(hi - lo, max_travel)
    qa = float(np.clip(centre - 0.5 * travel, lo, hi - travel))
    qb = qa + travel
    q_hold[joint] = qa
    vlim = robot.velocity_limit[joint]
    vmax = 0.9 * vlim if np.isfinite(vlim) and vlim > 0 else np.inf
    wanted = DEFAULT_SPEEDS if speeds is None else tuple(float(v) for v in speeds)
    if any(v <= 0 for v in wanted):
        raise ConfigError(f"speeds must be positive [rad/s]; got {list(wanted)}")
    usable = [v for v in wanted if v <= vmax and (travel - v * v / acceleration) / v >= MIN_CONSTANT_TIME]
    if not usable:
        raise ConfigError(
            f"no usable speed for joint {joint + 1} ({robot.joint_names[joint]}): travel {travel:.3g} rad, "
            f"velocity limit {vlim:.3g} rad/s, speeds {list(wanted)}"
        )
    rows = []
    t = dwell
    for v in usable:
        for a_, b_ in ((qa, qb), (qb, qa)):
            rows.append((t, a_, b_, v))
            t += _move_time(travel, v, acceleration) + dwell
    return ConstantVelocityTrajectory(joint, q_hold, np.array(rows), float(acceleration), float(dwell))
