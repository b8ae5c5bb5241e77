"""Single-joint friction identification (Sec. II-D-2, Fig. 4, Table I).

One joint at a time moves at a set of constant velocities, in positive and negative direction, while
the others hold still; the mean measured torque over each constant-speed interval, with the rigid-body
torque of the model removed, is the friction torque at that mean velocity. A Coulomb + viscous law
(optionally with an offset) is fitted to these points by least squares:

    tau_f(dq) = d_v dq + mu_C sgn(dq) [+ tau_off]

* :func:`plan_friction_experiment` builds the reference for one joint (:class:`ConstantVelocityTrajectory`,
  with ``sample(t)``), inside the joint's position limits and velocity limit; both live in
  :mod:`reflexarm.ident.friction.constant_velocity_trajectory` and are re-exported here.
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

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.identify import FrictionParameters
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.friction.constant_velocity_trajectory import (  # the planning constants stay importable from here
    DEFAULT_RAMP_ACCELERATION,  # noqa: F401
    DEFAULT_SPEEDS,  # noqa: F401
    MIN_CONSTANT_TIME,  # noqa: F401
    ConstantVelocityTrajectory,
    plan_friction_experiment,
)
from reflexarm.ident.friction.parameters import check_friction_against_robot, check_friction_plausibility
from reflexarm.robots.robot_model import RobotModel

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

#: Part of each constant-speed interval dropped at its start, for the controller to settle [s].
DEFAULT_SETTLE_TIME = 0.3


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


def fit_friction(
    points: Sequence[FrictionPoint], *, offset: bool = False, robot: RobotModel | None = None
) -> FrictionFit:
    """Least-squares fit of ``tau = d_v v + mu_C sgn(v) [+ offset]`` to the points of one joint.

    Warns (:class:`~reflexarm.ident.friction.parameters.ImplausibleFrictionWarning`) if mu_C or d_v comes
    out negative, or (given ``robot``: its effort and velocity limits) implausibly large.

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
    j = points[0].joint
    n = robot.n if robot is not None else j + 1
    at_j = np.arange(n) == j
    fitted = FrictionParameters(np.where(at_j, x[0], 0.0), np.where(at_j, x[1], 0.0))
    spread = FrictionParameters(np.where(at_j, np.sqrt(cov[0, 0]), 0.0), np.where(at_j, np.sqrt(cov[1, 1]), 0.0))
    where = "single-joint friction fit"
    if robot is not None:
        check_friction_against_robot(fitted, robot, joints=[j], std=spread, source=where, stacklevel=2)
    else:
        check_friction_plausibility(fitted, joints=[j], std=spread, source=where, stacklevel=2)
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
            (:func:`~reflexarm.logs.plausibility.check_samples_against_robot`; needs a robot).

    Raises:
        ImplausibleDataError: ``check_limits`` and a torque, velocity or position far beyond the robot's.
    """
    if check_limits and robot is not None:
        from reflexarm.logs.plausibility import check_samples_against_robot

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
    return fit_friction(friction_points(robot, joint, t, q, dq, tau, intervals), offset=offset, robot=robot)


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
