"""Single-joint friction identification (Sec. II-D-2, Fig. 4, Table I).

One joint at a time moves at a set of constant velocities, in positive and negative direction, while
the others hold still; the mean measured torque over each constant-speed interval, with the rigid-body
torque of the model removed, is the friction torque at that mean velocity. A Coulomb + viscous law
(optionally with an offset) is fitted to these points by least squares:

    tau_f(dq) = d_v dq + mu_C sgn(dq) [+ tau_off]

* :func:`plan_friction_experiment` builds the reference for one joint (:class:`ConstantVelocityTrajectory`,
  with ``sample(t)``), inside the joint's position limits and velocity limit.
* :func:`segment_constant_velocity` finds the constant-speed intervals in a measured velocity signal
  (without knowing the plan), or trims the planned ones.
* :func:`friction_points` averages velocity and rigid-body-corrected torque over the intervals.
* :func:`fit_friction` fits mu_C, d_v (and an offset).

Running the experiments on the simulated plant with the impedance controller (as the paper did, Fig. 5)
is :func:`reflexarm.experiments.identification.run_friction_experiments`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError, IdentificationError
from reflexarm.ident.estimation import FrictionParameters
from reflexarm.ident.regressor import BatchRegressor
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Reference

__all__ = [
    "ConstantVelocityTrajectory",
    "FrictionFit",
    "FrictionPoint",
    "fit_friction",
    "friction_from_fits",
    "friction_points",
    "identify_joint_friction",
    "plan_friction_experiment",
    "segment_constant_velocity",
]

#: Default speeds of the single-joint experiments [rad/s], each run in both directions.
DEFAULT_SPEEDS = (0.1, 0.2, 0.35, 0.5, 0.75, 1.0)
#: Default acceleration of the ramps between rest and constant speed [rad/s^2].
DEFAULT_RAMP_ACCELERATION = 3.0
#: Part of each constant-speed interval dropped at its start, for the controller to settle [s].
DEFAULT_SETTLE_TIME = 0.3
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


def segment_constant_velocity(
    t: npt.ArrayLike,
    dq: npt.ArrayLike,
    *,
    windows: np.ndarray | None = None,
    q: npt.ArrayLike | None = None,
    position_window: tuple[float, float] | None = None,
    settle: float = DEFAULT_SETTLE_TIME,
    min_speed: float = 0.02,
    tolerance: float = 0.02,
    min_duration: float = 0.2,
    smooth: float = 0.05,
) -> list[slice]:
    """Sample ranges of constant speed of one joint's velocity ``dq`` (N,).

    With ``windows`` (planned ``(t_begin, t_end, v)`` rows), each window minus ``settle`` seconds at its
    start is used. With ``q`` (the joint's positions) and ``position_window`` (lo, hi), each interval is
    further cut to the samples inside that position range. Without ``windows``, intervals are found from
    the data: the velocity is smoothed (moving average over ``smooth`` seconds), split where its sign
    changes, and the longest run within ``tolerance`` (relative) or three noise standard deviations of
    the median is kept; intervals shorter than ``min_duration`` [s] or slower than ``min_speed`` [rad/s]
    are dropped; ``settle`` seconds are dropped at each start. With ``q`` and no ``position_window``,
    the intervals are cut to the position range they all cover.
    """
    tt = np.asarray(t, dtype=float)
    v = np.asarray(dq, dtype=float).reshape(-1)
    if tt.size != v.size:
        raise IdentificationError(f"t and dq must have the same length; got {tt.size} and {v.size}")
    out: list[slice] = []
    if windows is not None:
        for t0, t1, _ in np.atleast_2d(windows):
            i0 = int(np.searchsorted(tt, t0 + settle))
            i1 = int(np.searchsorted(tt, t1))
            if i1 - i0 >= 2:
                out.append(slice(i0, i1))
        return _cut_to_positions(out, q, position_window)
    dt = float(np.median(np.diff(tt)))
    k = max(int(round(smooth / dt)), 1)
    vs = np.convolve(v, np.ones(k) / k, mode="same")
    moving = np.abs(vs) > min_speed
    sign = np.sign(vs) * moving
    edges = np.flatnonzero(np.diff(np.r_[0, sign, 0]) != 0)
    # noise of the smoothed velocity (robust: MAD of the part the smoothing removed)
    resid = v - vs
    noise = 1.4826 * float(np.median(np.abs(resid - np.median(resid)))) / np.sqrt(k)
    for s0, s1 in zip(edges[:-1], edges[1:], strict=True):
        if sign[s0] == 0:
            continue
        seg = vs[s0:s1]
        med = np.median(seg)
        steady = np.abs(seg - med) <= max(tolerance * abs(med), 3.0 * noise)
        # the longest run of steady samples
        runs = np.flatnonzero(np.diff(np.r_[0, steady.astype(int), 0]) != 0).reshape(-1, 2)
        if runs.size == 0:
            continue
        r0, r1 = max(runs, key=lambda r: r[1] - r[0])
        i0 = s0 + r0 + int(round(settle / dt))
        i1 = s0 + r1
        if (i1 - i0) * dt >= min_duration:
            out.append(slice(i0, i1))
    if position_window is None and q is not None and len(out) > 1:
        # the position range every interval covers: averaging all intervals over the same positions
        # keeps a position-dependent model error (gravity) out of the velocity dependence
        qj = np.asarray(q, dtype=float).reshape(-1)
        lo = max(float(qj[sl].min()) for sl in out)
        hi = min(float(qj[sl].max()) for sl in out)
        if hi > lo:
            position_window = (lo, hi)
    return _cut_to_positions(out, q, position_window)


def _cut_to_positions(
    intervals: list[slice], q: npt.ArrayLike | None, window: tuple[float, float] | None
) -> list[slice]:
    if window is None:
        return intervals
    if q is None:
        raise IdentificationError("position_window needs the joint positions q")
    qj = np.asarray(q, dtype=float).reshape(-1)
    lo, hi = window
    out = []
    for sl in intervals:
        inside = np.flatnonzero((qj[sl] >= lo) & (qj[sl] <= hi))
        if inside.size >= 2:
            out.append(slice(sl.start + int(inside[0]), sl.start + int(inside[-1]) + 1))
    return out


@dataclass(frozen=True)
class FrictionPoint:
    """One constant-speed interval: mean velocity [rad/s], mean friction torque [Nm], its spread."""

    joint: int
    velocity: float
    torque: float
    torque_std: float
    n_samples: int
    t_begin: float
    t_end: float


def friction_points(
    robot: RobotModel | None,
    joint: int,
    t: npt.ArrayLike,
    q: npt.ArrayLike,
    dq: npt.ArrayLike,
    tau: npt.ArrayLike,
    intervals: Sequence[slice],
) -> list[FrictionPoint]:
    """Mean velocity and mean friction torque of ``joint`` over each interval.

    The friction torque is ``tau_m - (C(q, dq) dq + g(q))`` with the model ``robot`` (the rigid-body
    torque at constant speed; ddq is taken as 0, its mean over a constant-speed interval). With
    ``robot=None`` the torque is used as is (e.g. when gravity does not act on the joint).
    """
    tt = np.asarray(t, dtype=float)
    Q = np.asarray(q, dtype=float)
    DQ = np.asarray(dq, dtype=float)
    TAU = np.asarray(tau, dtype=float)
    out = []
    for sl in intervals:
        tau_j = TAU[sl, joint].copy()
        if robot is not None:
            Y = BatchRegressor(robot).compute_regressor(Q[sl], DQ[sl], np.zeros_like(DQ[sl]))
            tau_j -= Y[:, joint, :] @ robot.inertial_parameters()
        out.append(
            FrictionPoint(
                joint=joint,
                velocity=float(DQ[sl, joint].mean()),
                torque=float(tau_j.mean()),
                torque_std=float(tau_j.std()),
                n_samples=int(sl.stop - sl.start),
                t_begin=float(tt[sl.start]),
                t_end=float(tt[sl.stop - 1]),
            )
        )
    return out


@dataclass(frozen=True)
class FrictionFit:
    """Coulomb + viscous (+ offset) fit of one joint's friction points.

    Attributes:
        joint: 0-based index.
        coulomb: mu_C [Nm]; viscous: d_v [Nms/rad]; offset: [Nm] or None.
        coulomb_std, viscous_std: standard errors from the fit residual [Nm], [Nms/rad].
        rms_residual: RMS of the fit residual over the points [Nm].
        points: the points fitted.
    """

    joint: int
    coulomb: float
    viscous: float
    offset: float | None
    coulomb_std: float
    viscous_std: float
    rms_residual: float
    points: tuple[FrictionPoint, ...] = field(default=())

    def compute_torque(self, dq: npt.ArrayLike) -> np.ndarray:
        v = np.asarray(dq, dtype=float)
        return self.viscous * v + self.coulomb * np.sign(v) + (self.offset or 0.0)


def fit_friction(points: Sequence[FrictionPoint], *, offset: bool = False) -> FrictionFit:
    """Least-squares fit of ``tau = d_v v + mu_C sgn(v) [+ offset]`` to the points of one joint.

    Raises:
        IdentificationError: fewer points than parameters, or no point in one of the two directions
            (Coulomb and offset are then indistinguishable).
    """
    if not points:
        raise IdentificationError("no friction points to fit")
    joints = {p.joint for p in points}
    if len(joints) != 1:
        raise IdentificationError(f"friction points of one joint expected; got joints {sorted(joints)}")
    v = np.array([p.velocity for p in points])
    tau = np.array([p.torque for p in points])
    cols = [v, np.sign(v)] + ([np.ones_like(v)] if offset else [])
    A = np.column_stack(cols)
    k = A.shape[1]
    if v.size < k + 1:
        raise IdentificationError(
            f"{v.size} friction points cannot determine {k} parameters with a residual; run more speeds"
        )
    if offset and (np.all(v > 0) or np.all(v < 0)):
        raise IdentificationError("Coulomb friction and an offset need points in both directions")
    x, *_ = np.linalg.lstsq(A, tau, rcond=None)
    r = tau - A @ x
    s2 = float(r @ r) / max(v.size - k, 1)
    cov = s2 * np.linalg.inv(A.T @ A)
    return FrictionFit(
        joint=points[0].joint,
        coulomb=float(x[1]),
        viscous=float(x[0]),
        offset=float(x[2]) if offset else None,
        coulomb_std=float(np.sqrt(cov[1, 1])),
        viscous_std=float(np.sqrt(cov[0, 0])),
        rms_residual=float(np.sqrt(np.mean(r**2))),
        points=tuple(points),
    )


def identify_joint_friction(
    robot: RobotModel | None,
    joint: int,
    t: npt.ArrayLike,
    q: npt.ArrayLike,
    dq: npt.ArrayLike,
    tau: npt.ArrayLike,
    *,
    windows: np.ndarray | None = None,
    position_window: tuple[float, float] | None = None,
    offset: bool = False,
    settle: float = DEFAULT_SETTLE_TIME,
    check_limits: bool = True,
) -> FrictionFit:
    """Segment, average and fit one joint's constant-velocity runs (see the module docstring).

    Args:
        robot: model whose rigid-body torque is removed (None: none removed).
        joint: 0-based joint index.
        t, q, dq, tau: the log of the runs (N,), (N, n).
        windows: the planned constant-speed intervals (:attr:`ConstantVelocityTrajectory.windows`); None:
            found from the data.
        position_window: common position range of the intervals
            (:meth:`ConstantVelocityTrajectory.position_window`).
        offset: fit an offset too.
        settle: seconds dropped at the start of each interval.
        check_limits: refuse runs far outside ``robot``'s limits, as :func:`identify_dynamics` does
            (:func:`~reflexarm.ident.plausibility.check_samples_against_robot`; needs a robot).

    Raises:
        ImplausibleDataError: ``check_limits`` and a torque, velocity or position far beyond the robot's.
    """
    if check_limits and robot is not None:
        from reflexarm.ident.plausibility import check_samples_against_robot

        check_samples_against_robot(f"joint {joint + 1} friction runs", t, q, dq, tau, robot)
    intervals = segment_constant_velocity(
        t,
        np.asarray(dq)[:, joint],
        windows=windows,
        q=np.asarray(q)[:, joint],
        position_window=position_window,
        settle=settle,
    )
    if not intervals:
        raise IdentificationError(f"joint {joint + 1}: no constant-velocity interval found in the data")
    return fit_friction(friction_points(robot, joint, t, q, dq, tau, intervals), offset=offset)


def friction_from_fits(
    fits: Sequence[FrictionFit], n: int, *, default: FrictionParameters | None = None
) -> FrictionParameters:
    """Assemble per-joint fits into :class:`FrictionParameters` (joints without a fit: ``default`` or 0)."""
    viscous = np.zeros(n) if default is None else default.viscous.copy()
    coulomb = np.zeros(n) if default is None else default.coulomb.copy()
    have_offset = any(f.offset is not None for f in fits)
    offset = (
        (np.zeros(n) if default is None or default.offset is None else default.offset.copy()) if have_offset else None
    )
    for f in fits:
        viscous[f.joint] = f.viscous
        coulomb[f.joint] = f.coulomb
        if offset is not None and f.offset is not None:
            offset[f.joint] = f.offset
    return FrictionParameters(viscous, coulomb, offset)
