"""The rows of (19) and their reduction to per-joint normal equations (the first half of
:func:`~reflexarm.ident.estimation.identify.identify_dynamics`).

:class:`RegressionProblem` holds what the options decide (which friction columns are estimated, the offsets,
the wrist wrench column, the given friction of eq. (16), the weights' source) and a
:class:`~reflexarm.ident.estimation._weighted_least_squares._GramAccumulator`. Logs are added to it
whole (:meth:`RegressionProblem.add_log`, chunk by chunk) or block by block as a streamed log is read
(:mod:`reflexarm.ident.estimation.streaming`): the normal equations are sums over rows, so the order of
the blocks is the only difference.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation._weighted_least_squares import _GramAccumulator
from reflexarm.ident.estimation.base_parameters import BaseParameters, compute_base_parameters
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.estimation.result import _CHUNK
from reflexarm.ident.friction.parameters import FrictionParameters, format_joints
from reflexarm.logs._measured_torque import _rhs
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

#: The two estimation methods of Sec. II-D.
METHODS = ("sequential", "combined")


@dataclass
class RegressionProblem:
    """The columns of (19) the options ask for, and the normal equations of the rows added so far."""

    robot: RobotModel
    method: str
    base: BaseParameters
    fixed: FrictionParameters | None  # the given friction (sequential), else None
    fric_est: tuple[int, ...]  # joints whose d_v, mu_C are columns of (19)
    est_offset: bool
    has_wrench: bool  # the wrist wrench's torque -J^T F is one more column while its use is decided
    wrench: str
    min_speed: float
    noise_variance: Any
    given_variance: np.ndarray | None
    acc: _GramAccumulator = field(init=False)
    reg: BatchRegressor = field(init=False)
    known: KnownJointTerms = field(init=False)
    total: int = 0
    t_reg: float = 0.0
    t_solve: float = 0.0

    def __post_init__(self) -> None:
        self.acc = _GramAccumulator(self.robot.n, self.p_acc)
        self.reg = BatchRegressor(self.robot)
        self.known = KnownJointTerms.from_robot(self.robot)

    @property
    def n(self) -> int:
        return self.robot.n

    @property
    def nb(self) -> int:
        return self.base.n_base

    @property
    def n_fe(self) -> int:
        return len(self.fric_est)

    @property
    def p(self) -> int:
        """Unknowns of the final problem: beta_b, the estimated friction, the offsets."""
        return self.nb + 2 * self.n_fe + (self.n if self.est_offset else 0)

    @property
    def p_acc(self) -> int:
        return self.p + int(self.has_wrench)

    def rows(self, dq: np.ndarray, b: np.ndarray, w: np.ndarray | None, Y: np.ndarray) -> np.ndarray:
        """Rows [Phi_b (Phi_f) (offsets) (-J^T F) | b] of (19), per joint: (n, m, p_acc + 1)."""
        n, nb, n_fe, p, p_acc = self.n, self.nb, self.n_fe, self.p, self.p_acc
        M = np.zeros((n, Y.shape[0], p_acc + 1))
        M[:, :, :nb] = np.take(Y, self.base.independent, axis=2).transpose(1, 0, 2)
        k = nb
        idx = np.arange(n)
        if n_fe:  # eq. (15): each joint's friction columns act on its own rows only
            fe, i = np.asarray(self.fric_est, dtype=int), np.arange(n_fe)
            M[fe, :, k + i] = dq[:, fe].T
            M[fe, :, k + n_fe + i] = np.sign(dq[:, fe]).T
            k += 2 * n_fe
        if self.fixed is not None:  # eq. (16) on the joints with given friction
            given = ~np.isnan(self.fixed.viscous)
            b = b - (
                np.where(given, self.fixed.viscous, 0.0) * dq + np.where(given, self.fixed.coulomb, 0.0) * np.sign(dq)
            )
            if self.fixed.offset is not None:
                b = b - self.fixed.offset
        if self.est_offset:
            M[idx, :, k + idx] = 1.0
        if self.has_wrench and w is not None:
            M[:, :, p] = -w.T
        M[:, :, p_acc] = b.T
        return M

    def add_log(self, lg: RobotLog, chunks: Callable[[Iterator[Any], RobotLog], Iterator[Any]] | None = None) -> None:
        """Reduce the rows of one preprocessed log (or one block of it) into the normal equations."""
        add_rows([self], lg, chunks)

    def _targets(self, lg: RobotLog) -> tuple[np.ndarray, np.ndarray | None]:
        """(b before eq. (16): the measured torque less the known terms, J^T F per sample or None)."""
        assert lg.ddq is not None  # checked by check_logs
        b_all = lg.tau.copy()
        w_all = None if lg.wrench is None or self.wrench == "exclude" else _rhs(self.robot, lg) - lg.tau  # J^T F
        if not self.known.is_zero:  # the file's armature and springs are given, not identified
            b_all -= self.known.compute_torque(lg.q, lg.ddq)
        return b_all, w_all


def add_rows(
    problems: Sequence[RegressionProblem],
    lg: RobotLog,
    chunks: Callable[[Iterator[Any], RobotLog], Iterator[Any]] | None = None,
) -> None:
    """Reduce the rows of one preprocessed log (or a block of it) into each problem's normal equations, the
    regressor evaluated once for all of them (same robot)."""
    assert lg.ddq is not None  # checked by check_logs
    clock = time.perf_counter()
    targets = [pb._targets(lg) for pb in problems]
    share = (time.perf_counter() - clock) / len(problems)
    for pb in problems:
        pb.t_reg += share
    it = problems[0].reg.iter_chunks(lg.q, lg.dq, lg.ddq, _CHUNK)
    it = chunks(it, lg) if chunks is not None else it
    while True:
        clock = time.perf_counter()
        try:
            sl, Y = next(it)
        except StopIteration:
            break
        dq = lg.dq[sl]
        share = (time.perf_counter() - clock) / len(problems)
        for pb, (b_all, w_all) in zip(problems, targets, strict=True):
            clock = time.perf_counter()
            M = pb.rows(dq, b_all[sl], None if w_all is None else w_all[sl], Y)
            keep = np.abs(dq) >= pb.min_speed if pb.min_speed > 0 else None
            pb.t_reg += share + time.perf_counter() - clock
            clock = time.perf_counter()
            pb.acc.add(M, keep)
            pb.t_solve += time.perf_counter() - clock
    for pb in problems:
        pb.total += len(lg)


def check_logs(logs: Sequence[RobotLog], robot: RobotModel, check_limits: bool) -> None:
    """Joint counts, ddq present, and (``check_limits``) the logs against the robot's limits."""
    from reflexarm.logs.plausibility import check_log_against_robot

    for lg in logs:
        check_log(lg.source, lg.n, lg.ddq is not None, robot)
        if check_limits:
            check_log_against_robot(lg, robot)


def check_log(source: str, n: int, has_ddq: bool, robot: RobotModel) -> None:
    """One log's joint count and ddq."""
    if n != robot.n:
        raise IdentificationError(f"{source}: log has {n} joints; robot {robot.name!r} has {robot.n}")
    if not has_ddq:
        raise IdentificationError(
            f"{source}: log has no ddq; run reflexarm.ident.preprocess_log first (filtering and differentiation)"
        )


def setup_problem(
    robot: RobotModel,
    method: str,
    friction: FrictionParameters | CoulombViscousFriction | None,
    offset: bool,
    noise_variance: npt.ArrayLike | str | None,
    base: BaseParameters | None,
    min_speed: float,
    wrench: str,
    log_has_wrench: bool,
) -> RegressionProblem:
    """The options checked and turned into the columns of (19) (``log_has_wrench``: some log has a wrench)."""
    if method not in METHODS:
        raise IdentificationError(f"unknown identification method {method!r}; choose one of: {', '.join(METHODS)}")
    n = robot.n
    fixed = _fixed_friction(robot, method, friction)
    if wrench not in ("auto", "include", "exclude"):
        raise IdentificationError(f"wrench must be 'auto', 'include' or 'exclude'; got {wrench!r}")
    # joints whose d_v, mu_C are columns of (19): every joint (combined); those the given friction does not
    # know (sequential: no single-joint run), whose torque would otherwise be corrected with 0 friction
    fric_est = tuple(range(n)) if fixed is None else fixed.missing
    return RegressionProblem(
        robot=robot,
        method=method,
        base=base if base is not None else compute_base_parameters(robot),
        fixed=fixed,
        fric_est=fric_est,
        est_offset=offset and (fixed is None or fixed.offset is None),
        has_wrench=log_has_wrench and wrench != "exclude",
        wrench=wrench,
        min_speed=min_speed,
        noise_variance=noise_variance,
        given_variance=_given_variance(noise_variance, n),
    )


def _fixed_friction(
    robot: RobotModel, method: str, friction: FrictionParameters | CoulombViscousFriction | None
) -> FrictionParameters | None:
    if method != "sequential":
        return None
    if friction is None:
        raise IdentificationError(
            "method 'sequential' needs the pre-identified friction (friction=...; see identify_joint_friction)"
        )
    fixed = FrictionParameters.from_model(friction) if isinstance(friction, CoulombViscousFriction) else friction
    if fixed.n != robot.n:
        raise IdentificationError(f"friction has {fixed.n} joints; robot {robot.name!r} has {robot.n}")
    if fixed.missing and fixed.offset is not None:
        raise IdentificationError(
            f"the given friction has offsets but no friction for joint(s) "
            f"{format_joints(fixed.missing, robot.joint_names)}: give it without offsets (offset=True then "
            "estimates every joint's offset) or with every joint's friction and offset"
        )
    return fixed


def _given_variance(noise_variance: npt.ArrayLike | str | None, n: int) -> np.ndarray | None:
    """Per-joint variances given by the caller; None for 'estimate' or unweighted."""
    if isinstance(noise_variance, str):
        if noise_variance != "estimate":
            raise IdentificationError(
                f"noise_variance must be per-joint variances, 'estimate' or None; got {noise_variance!r}"
            )
        return None
    if noise_variance is None:
        return None
    nv = np.asarray(noise_variance, dtype=float).reshape(-1)
    if nv.size not in (1, n):
        raise IdentificationError(
            f"noise_variance must be one variance or one per joint ({n}); got {nv.size}: {nv.tolist()}"
        )
    given = np.broadcast_to(nv, (n,)).copy()
    if not np.all(np.isfinite(given)) or np.any(given <= 0):
        raise IdentificationError(f"noise_variance must be positive per joint; got {given.tolist()}")
    return given
