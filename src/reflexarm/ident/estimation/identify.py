"""Weighted least squares for the base and friction parameters, eqs. (14)-(19): combined and sequential.

The model (14) with tau_ext = 0 (or removed with the wrist wrench) and the friction regressor (15):

    tau_m = Phi_b(q, dq, ddq) beta_b + diag(dq) d_v + diag(sgn dq) mu_C [+ tau_off]

* **combined** (the paper's beta_I, their earlier work [24]): beta_b, d_v, mu_C (and the offsets)
  estimated together in one weighted least-squares problem.
* **sequential** (the paper's beta_II): d_v, mu_C come from the single-joint constant-velocity
  experiments (:mod:`reflexarm.ident.friction.joint_friction`); the friction-corrected torque (16)-(17)
  ``tau_m,f = tau_m - Phi_f (d_v, mu_C)`` is then explained by Phi_b beta_b alone (45 instead of 59
  unknowns on the Atlas arm). Joints the given friction does not know (NaN: no single-joint run, e.g.
  the Atlas wrist when only the hydraulic joints were run) keep their friction columns and are
  estimated with beta_b (45 + 2 per such joint unknowns), never corrected with a zero friction; the
  result says so in its notes and records them (``DynamicsIdentification.friction_estimated``).

Both solve (18), ``beta = (F^T Sigma^-1 F)^-1 F^T Sigma^-1 b``, with F and b stacked over the samples as in
(19) and ``Sigma = diag(sigma_1^2, ..., sigma_n^2)`` repeated per sample: each joint's rows are weighted
by its torque noise variance. The variances are given (e.g. the sensor's) or estimated from the
residuals of an ordinary least-squares pass (``noise_variance="estimate"``, the usual two-step
weighting of Gautier and Swevers). The rows are reduced chunk by chunk to per-joint information matrices
(see ``_GramAccumulator``), so memory stays bounded for long logs.

Offsets (``offset=True``): a constant torque per joint, a friction-model extra for a torque sensor's
bias or an asymmetric friction (the Panda's identified friction law has one, see Gaz et al. 2019). In
the sequential method the offsets are estimated together with beta_b unless the given friction has
them.

Known joint terms: a robot file's rotor armature and joint springs (``diag(I_a) ddq + K_s (q - q_s)``,
:mod:`reflexarm.ident.estimation.known_terms`) are not in the inertial regressor Phi_b. Both methods take them from
the file and subtract them from the measured torque before the regression, like the friction correction
(16); the result records them (``DynamicsIdentification.known_terms`` and a note) and adds them back in
its predictions.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError, NonFiniteEstimateError
from reflexarm.ident._blas_threads import DEFAULT_BLAS_THREADS, blas_threads
from reflexarm.ident.estimation._weighted_least_squares import _GramAccumulator
from reflexarm.ident.estimation.base_parameters import (
    BaseParameters,
    compute_base_parameters,
    warn_if_ill_conditioned,
)
from reflexarm.ident.estimation.inertia_determinacy import (
    assess_inertia_determinacy,
    filtered_rows_factor,
    warn_if_poorly_determined,
)
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.estimation.result import (
    _CHUNK,
    DynamicsIdentification,
    PhysicalConsistencyWarning,
    mass_matrix_margin,
    save_identification,
)
from reflexarm.ident.estimation.validation import TorqueValidation, validate_model
from reflexarm.ident.estimation.wrist_wrench import WristWrenchDecision, decide_wrist_wrench
from reflexarm.ident.friction.parameters import FrictionParameters, check_friction_against_robot, format_joints
from reflexarm.logs._measured_torque import _rhs
from reflexarm.logs.plausibility import check_log_against_robot, likely_bad_rows
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

# DynamicsIdentification, FrictionParameters, TorqueValidation, ... live in their own modules
# (identification_result, friction_parameters, validation) and are re-exported here, where they have
# always been imported from.
__all__ = [
    "METHODS",
    "DynamicsIdentification",
    "FrictionParameters",
    "PhysicalConsistencyWarning",
    "TorqueValidation",
    "identify_dynamics",
    "mass_matrix_margin",
    "save_identification",
    "validate_model",
]

#: The two estimation methods of Sec. II-D.
METHODS = ("sequential", "combined")

#: Condition number of the column-normalised weighted regressor above which identification warns.
#: Column normalisation makes the number independent of parameter units; above ~1e3 a 1 % torque error
#: can move some parameter combination by more than 10 times its share of the torque.
DEFAULT_CONDITION_LIMIT = 1e3


def identify_dynamics(
    robot: RobotModel,
    log: RobotLog | Sequence[RobotLog],
    *,
    method: Literal["sequential", "combined"] = "sequential",
    friction: FrictionParameters | CoulombViscousFriction | None = None,
    offset: bool = False,
    noise_variance: npt.ArrayLike | Literal["estimate"] | None = "estimate",
    base: BaseParameters | None = None,
    condition_limit: float = DEFAULT_CONDITION_LIMIT,
    min_speed: float = 0.0,
    progress: bool = False,
    check_limits: bool = True,
    threads: int | None = DEFAULT_BLAS_THREADS,
    filter_cutoff_hz: float | None = None,
    wrench: Literal["auto", "include", "exclude"] = "auto",
) -> DynamicsIdentification:
    """Identify beta_b (and friction) from a log by weighted least squares, eq. (18).

    Args:
        robot: the arm (kinematics, and its file's armature and joint springs, which are subtracted from
            the measured torque as known terms; the nominal inertias are not used).
        log: one or more preprocessed logs (with ``ddq``, see :func:`~reflexarm.ident.preprocess_log`).
        method: ``"sequential"`` (friction fixed to ``friction``, eqs. (16)-(17)) or ``"combined"``.
        friction: the pre-identified friction for ``sequential`` (required there, ignored otherwise); joints
            it does not know (NaN, :attr:`FrictionParameters.missing`) get their d_v, mu_C estimated here.
        offset: also estimate a constant torque per joint (see the module docstring).
        noise_variance: sigma_j^2 per joint [Nm^2] for Sigma; ``"estimate"``: from the residuals of an
            unweighted pass; None: unweighted (Sigma = I).
        base: base-parameter map (default: computed from ``robot``).
        condition_limit: warn (:class:`IllConditionedWarning`) above this condition number.
        min_speed: leave out the rows (joint j at sample k) with |dq_j| < min_speed [rad/s]: there the
            sign of the velocity, hence the Coulomb torque, is undetermined (sticking, or speeds within
            the velocity noise). Each joint's rows are separate equations of (19), so this drops no
            other joint's information. Default 0: every row is used.
        progress: show a progress bar over the regressor chunks.
        check_limits: refuse logs that leave the robot's limits by far
            (:func:`~reflexarm.logs.plausibility.check_log_against_robot`: torque beyond 10 x the effort
            limit, velocity beyond 10 x the velocity limit, position a quarter turn outside the range).
        threads: BLAS threads for the Gram products and solves (default 1, see
            :mod:`reflexarm.ident._blas_threads`: many BLAS threads lose badly on a busy machine); None
            leaves BLAS as configured.
        filter_cutoff_hz: the low-pass cutoff the logs were preprocessed with, if any: their rows' errors are
            then correlated, and the M(q) uncertainty scales its covariance (see
            :mod:`reflexarm.ident.estimation.inertia_determinacy`; the parameter std ``beta_std`` is not scaled).
        wrench: the logs' wrist wrench: ``"auto"`` (default) includes it when the data say it explains the
            torque and leaves it out when it carries only noise (:mod:`reflexarm.ident.estimation.wrist_wrench`;
            the result's notes give the numbers); ``"include"`` or ``"exclude"`` decide without asking.

    Warns:
        IllConditionedWarning: the regressor is rank deficient or its condition number (column-
            normalised, weighted) exceeds ``condition_limit``; the message gives the condition number.
        PoorlyDeterminedInertiaWarning: the data determine M(q) poorly (1-sigma relative uncertainty above
            15 % at some posture; ``result.inertia_determinacy`` holds the numbers).

    Raises:
        IdentificationError: unknown method, missing friction for ``sequential``, log without ddq,
            joint count mismatch, noise variances of the wrong count, a joint left without rows by
            ``min_speed``, given offsets without the friction of some joints.
        NonFiniteEstimateError: (an IdentificationError) the solution is NaN/inf; the message and its
            ``samples`` name the rows that stand out most from their columns (the likely bad rows).
        ImplausibleDataError: (a DataError) ``check_limits`` and a log far outside the robot's limits;
            the message names the rows, columns, values and bounds.
    """
    with blas_threads(threads):
        return _identify_dynamics(
            robot, log, method, friction, offset, noise_variance, base, condition_limit, min_speed, progress,
            check_limits, filter_cutoff_hz, wrench,
        )  # fmt: skip


def _identify_dynamics(
    robot: RobotModel,
    log: RobotLog | Sequence[RobotLog],
    method: str,
    friction: FrictionParameters | CoulombViscousFriction | None,
    offset: bool,
    noise_variance: npt.ArrayLike | Literal["estimate"] | None,
    base: BaseParameters | None,
    condition_limit: float,
    min_speed: float,
    progress: bool,
    check_limits: bool,
    filter_cutoff_hz: float | None = None,
    wrench: str = "auto",
) -> DynamicsIdentification:
    """:func:`identify_dynamics` with BLAS threads set."""
    if method not in METHODS:
        raise IdentificationError(f"unknown identification method {method!r}; choose one of: {', '.join(METHODS)}")
    logs = [log] if isinstance(log, RobotLog) else list(log)
    if not logs:
        raise IdentificationError("no log given")
    n = robot.n
    for lg in logs:
        if lg.n != n:
            raise IdentificationError(f"{lg.source}: log has {lg.n} joints; robot {robot.name!r} has {n}")
        if lg.ddq is None:
            raise IdentificationError(
                f"{lg.source}: log has no ddq; run reflexarm.ident.preprocess_log first (filtering and differentiation)"
            )
        if check_limits:
            check_log_against_robot(lg, robot)
    fixed: FrictionParameters | None = None
    if method == "sequential":
        if friction is None:
            raise IdentificationError(
                "method 'sequential' needs the pre-identified friction (friction=...; see identify_joint_friction)"
            )
        fixed = FrictionParameters.from_model(friction) if isinstance(friction, CoulombViscousFriction) else friction
        if fixed.n != n:
            raise IdentificationError(f"friction has {fixed.n} joints; robot {robot.name!r} has {n}")
        if fixed.missing and fixed.offset is not None:
            raise IdentificationError(
                f"the given friction has offsets but no friction for joint(s) "
                f"{format_joints(fixed.missing, robot.joint_names)}: give it without offsets (offset=True then "
                "estimates every joint's offset) or with every joint's friction and offset"
            )
    # joints whose d_v, mu_C are columns of (19): every joint (combined); those the given friction does not
    # know (sequential: no single-joint run), whose torque would otherwise be corrected with 0 friction
    fric_est = tuple(range(n)) if fixed is None else fixed.missing
    n_fe = len(fric_est)
    fe = np.asarray(fric_est, dtype=int)
    base = base if base is not None else compute_base_parameters(robot)
    reg = BatchRegressor(robot)
    known = KnownJointTerms.from_robot(robot)
    nb = base.n_base
    est_offset = offset and (fixed is None or fixed.offset is None)
    p = nb + 2 * n_fe + (n if est_offset else 0)
    if wrench not in ("auto", "include", "exclude"):
        raise IdentificationError(f"wrench must be 'auto', 'include' or 'exclude'; got {wrench!r}")
    # the wrist wrench's torque -J^T F is one more column while its use is decided (wrist_wrench)
    has_wrench = any(lg.wrench is not None for lg in logs) and wrench != "exclude"
    p_acc = p + int(has_wrench)
    if fixed is not None:  # eq. (16) on the joints with given friction; the others' friction is estimated
        given = ~np.isnan(fixed.viscous)
        fixed_viscous = np.where(given, fixed.viscous, 0.0)
        fixed_coulomb = np.where(given, fixed.coulomb, 0.0)

    def rows(lg: RobotLog, b_all: np.ndarray, w_all: np.ndarray | None, sl: slice, Y: np.ndarray) -> np.ndarray:
        """Rows [Phi_b (Phi_f) (offsets) (-J^T F) | b] of (19), per joint: (n, m, p_acc + 1)."""
        m = Y.shape[0]
        M = np.zeros((n, m, p_acc + 1))
        M[:, :, :nb] = np.take(Y, base.independent, axis=2).transpose(1, 0, 2)
        b = b_all[sl]
        dq = lg.dq[sl]
        k = nb
        idx = np.arange(n)
        if n_fe:  # eq. (15): each joint's friction columns act on its own rows only
            i = np.arange(n_fe)
            M[fe, :, k + i] = dq[:, fe].T
            M[fe, :, k + n_fe + i] = np.sign(dq[:, fe]).T
            k += 2 * n_fe
        if fixed is not None:
            b = b - (fixed_viscous * dq + fixed_coulomb * np.sign(dq))  # eq. (16)
            if fixed.offset is not None:
                b = b - fixed.offset
        if est_offset:
            M[idx, :, k + idx] = 1.0
        if has_wrench and w_all is not None:
            M[:, :, p] = -w_all[sl].T
        M[:, :, p_acc] = b.T
        return M

    # weights: given, estimated from an unweighted pass, or none
    given = None
    if isinstance(noise_variance, str):
        if noise_variance != "estimate":
            raise IdentificationError(
                f"noise_variance must be per-joint variances, 'estimate' or None; got {noise_variance!r}"
            )
    elif noise_variance is not None:
        nv = np.asarray(noise_variance, dtype=float).reshape(-1)
        if nv.size not in (1, n):
            raise IdentificationError(
                f"noise_variance must be one variance or one per joint ({n}); got {nv.size}: {nv.tolist()}"
            )
        given = np.broadcast_to(nv, (n,)).copy()
        if not np.all(np.isfinite(given)) or np.any(given <= 0):
            raise IdentificationError(f"noise_variance must be positive per joint; got {given.tolist()}")
    total = sum(len(lg) for lg in logs)
    acc = _GramAccumulator(n, p_acc)
    t_reg = t_solve = 0.0
    for lg in logs:
        assert lg.ddq is not None  # checked above
        clock = time.perf_counter()
        b_all = lg.tau.copy()
        w_all = None if lg.wrench is None else _rhs(robot, lg) - lg.tau  # J^T F per sample
        if w_all is not None and wrench == "exclude":
            w_all = None
        if not known.is_zero:  # the file's armature and springs are given, not identified
            b_all -= known.compute_torque(lg.q, lg.ddq)
        t_reg += time.perf_counter() - clock
        chunks = _progress(reg.iter_chunks(lg.q, lg.dq, lg.ddq, _CHUNK), progress, lg)
        while True:
            clock = time.perf_counter()
            try:
                sl, Y = next(chunks)
            except StopIteration:
                break
            M = rows(lg, b_all, w_all, sl, Y)
            keep = np.abs(lg.dq[sl]) >= min_speed if min_speed > 0 else None
            t_reg += time.perf_counter() - clock
            clock = time.perf_counter()
            acc.add(M, keep)
            t_solve += time.perf_counter() - clock
    _refuse_non_finite({"entries of the information matrix": acc.G}, logs)
    if np.any(acc.rows == 0):  # only min_speed removes rows: no equation of the joint is left
        empty = tuple(int(j) for j in np.flatnonzero(acc.rows == 0))
        raise IdentificationError(
            f"joint(s) {format_joints(empty, robot.joint_names)}: no sample left with |dq_j| >= min_speed = "
            f"{min_speed:g} rad/s in {total:,} samples; their torque would not enter the fit. Lower min_speed or "
            "log motion of these joints"
        )
    clock = time.perf_counter()
    notes: list[str] = [] if known.is_zero else [known.describe()]
    if has_wrench:
        row_corr = filtered_rows_factor([float(np.median(np.diff(lg.t))) for lg in logs], filter_cutoff_hz)
        acc, decision = _settle_wrench(acc, p, wrench, row_corr)
        notes.append(decision.reason)
    elif any(lg.wrench is not None for lg in logs):
        notes.append("wrist wrench left out as asked (wrench='exclude')")
    if given is not None:
        sigma2 = given
        notes.append(
            "Sigma from the given per-joint noise variances: " + ", ".join(f"{s:.3g}" for s in sigma2) + " Nm^2"
        )
    elif noise_variance is None:
        sigma2 = np.ones(n)
        notes.append("unweighted least squares (Sigma = I)")
    else:
        # per-joint residual variance of an unweighted fit -> Sigma of (18)
        x0 = acc.solve(np.ones(n)).x
        sigma2 = np.maximum(acc.residual_ss(x0) / np.maximum(acc.rows - p / n, 1.0), 1e-12)
        _refuse_non_finite({"unweighted parameters": x0, "noise variances": sigma2}, logs)
        notes.append(
            "Sigma from the per-joint residual variances of an unweighted pass: "
            + ", ".join(f"{s:.3g}" for s in sigma2)
            + " Nm^2"
        )
    sol = acc.solve(1.0 / np.sqrt(sigma2))
    x, cond = sol.x, sol.condition_number
    t_solve += time.perf_counter() - clock
    what = f"the identification regressor ({p} parameters, {int(acc.rows.max()):,} samples)"
    warn_if_ill_conditioned(cond, what, condition_limit, sol.rank_deficiency)
    if sol.rank_deficiency:
        notes.append(
            f"rank deficient by {sol.rank_deficiency}: the unexcited parameter combinations got the minimum-norm "
            "estimate (in column-normalised coordinates)"
        )
    # parameter standard deviations: s^2 (F^T W F)^+ with s^2 the weighted residual variance
    dof = max(int(acc.rows.sum()) - p, 1)
    s2 = sol.residual_norm**2 / dof
    std = np.sqrt(np.maximum(s2 * np.diag(sol.covariance), 0.0))
    residual_rms = np.sqrt(acc.residual_ss(x) / np.maximum(acc.rows, 1))
    _refuse_non_finite({"parameters": x, "standard deviations": std, "residual RMS": residual_rms}, logs)
    if min_speed > 0:
        notes.append(
            f"rows with |dq_j| < {min_speed:g} rad/s left out: "
            + ", ".join(f"{100 * (1 - r / total):.0f} %" for r in acc.rows)
            + " of each joint's samples"
        )
    beta_b = x[:nb]
    # how well M(q) is determined, from the covariance s^2 (F^T W F)^+ of beta_b (inertia_determinacy)
    determinacy = assess_inertia_determinacy(
        robot, base, beta_b, s2 * sol.covariance[:nb, :nb], armature=known.armature,
        row_correlation=filtered_rows_factor([float(np.median(np.diff(lg.t))) for lg in logs], filter_cutoff_hz),
    )  # fmt: skip
    warn_if_poorly_determined(determinacy, f"{method} identification", stacklevel=4)
    k = nb
    viscous = np.zeros(n) if fixed is None else fixed.viscous.copy()  # combined: every entry estimated below
    coulomb = np.zeros(n) if fixed is None else fixed.coulomb.copy()
    viscous[fe], coulomb[fe] = x[k : k + n_fe], x[k + n_fe : k + 2 * n_fe]
    fr = FrictionParameters(viscous, coulomb, None if fixed is None else fixed.offset)
    k += 2 * n_fe
    if est_offset:
        fr = replace(fr, offset=x[k : k + n])
    if n_fe:
        v_std, c_std = np.zeros(n), np.zeros(n)
        v_std[fe], c_std[fe] = std[nb : nb + n_fe], std[nb + n_fe : nb + 2 * n_fe]
        check_friction_against_robot(
            fr,
            robot,
            joints=fric_est,
            std=FrictionParameters(v_std, c_std),
            source=f"{method} identification",
            stacklevel=4,
        )
    if method == "sequential" and n_fe:
        notes.append(
            f"the given friction has none for joint(s) {format_joints(fric_est, robot.joint_names)} (not identified): "
            f"their d_v, mu_C were estimated with beta_b ({nb} + {2 * n_fe} unknowns); the other joints' friction "
            "is the given one (eq. 16)"
        )
    return DynamicsIdentification(
        method=method,
        robot_name=robot.name,
        joint_names=tuple(robot.joint_names),
        base=base,
        beta_b=beta_b,
        friction=fr,
        beta_std=std,
        noise_variance=sigma2,
        condition_number=cond,
        n_samples=total,
        residual_rms=residual_rms,
        notes=tuple(notes),
        timings={"regressor_s": t_reg, "solve_s": t_solve},
        information=sol.information,
        known_terms=known,
        friction_estimated=fric_est,
        inertia_determinacy=determinacy,
    )


def _settle_wrench(
    acc: _GramAccumulator, p: int, wrench: str, row_correlation: float
) -> tuple[_GramAccumulator, WristWrenchDecision]:
    """Estimate alpha (the column p of ``acc``, two-step weighted), decide (:mod:`.wrist_wrench`) and return
    the accumulator with the wrench moved into b (included: b = tau + J^T F) or dropped."""
    x0 = acc.solve(np.ones(acc.n)).x
    sigma2 = np.maximum(acc.residual_ss(x0) / np.maximum(acc.rows - (p + 1) / acc.n, 1.0), 1e-12)
    sol = acc.solve(1.0 / np.sqrt(sigma2))
    dof = max(int(acc.rows.sum()) - p - 1, 1)
    alpha = float(sol.x[p])
    alpha_std = float(np.sqrt(max(sol.residual_norm**2 / dof * sol.covariance[p, p] * row_correlation, 0.0)))
    decision = decide_wrist_wrench(alpha, alpha_std)
    if wrench != "auto":
        included = wrench == "include"
        decision = decision._replace(
            included=included, reason=f"wrist wrench {'included' if included else 'left out'} as asked ({wrench=}; "
            f"the data give alpha = {alpha:.3g} +- {alpha_std:.2g})",
        )  # fmt: skip
    # [A, -J^T F, tau] -> [A, tau + J^T F] (included) or [A, tau] (left out)
    T = np.zeros((p + 2, p + 1))
    T[:p, :p] = np.eye(p)
    T[p + 1, p] = 1.0
    T[p, p] = -1.0 if decision.included else 0.0
    return acc.transformed(T), decision


def _refuse_non_finite(values: dict[str, np.ndarray], logs: Sequence[RobotLog]) -> None:
    """Raise :class:`NonFiniteEstimateError` naming the likely bad rows if any of ``values`` is NaN/inf."""
    bad = {name: int(np.sum(~np.isfinite(v))) for name, v in values.items() if not np.all(np.isfinite(v))}
    if not bad:
        return
    suspects = likely_bad_rows(logs)
    what = ", ".join(f"{k} of {values[name].size} {name}" for name, k in bad.items())
    if suspects:
        listed = "; ".join(f"{s.source} {s} (its column's 99th percentile {s.reference:.3g})" for s in suspects)
        cause = f"the rows that stand out most from their columns (likely bad rows): {listed}. Remove or repair them"
    else:
        cause = "no row stands out from its column; check the given noise variances (tiny ones overflow the weights)"
    raise NonFiniteEstimateError(
        f"identification gave non-finite results ({what}): the weighted least-squares problem overflowed; {cause}",
        tuple(suspects),
    )


def _progress(it, progress: bool, lg: RobotLog):  # type: ignore[no-untyped-def]
    from reflexarm._progress import show_progress

    if not show_progress(progress):
        yield from it
        return
    from tqdm import tqdm

    with tqdm(total=len(lg), desc=f"regressor {lg.source}", unit="sample", leave=False) as bar:
        for sl, Y in it:
            yield sl, Y
            bar.update(sl.stop - sl.start)


#: A projection that moves beta_b by more than this share of its norm is explained (which combinations
#: moved, by how many of their standard deviations): beyond 10 %, the model a user loads is not the fit.
PROJECTION_EXPLAIN = 0.1


def explain_projection(before: DynamicsIdentification, after: DynamicsIdentification, *, top: int = 3) -> str:
    """Why the physically consistent model ``after`` differs much from the least-squares ``before``: the base
    combinations that moved most, their change in standard deviations of the estimate, and what that means;
    "" when |delta beta_b| / |beta_b| <= :data:`PROJECTION_EXPLAIN`."""
    d = after.beta_b - before.beta_b
    rel = float(np.linalg.norm(d) / max(float(np.linalg.norm(before.beta_b)), 1e-300))
    if rel <= PROJECTION_EXPLAIN:
        return ""
    nb = before.base.n_base
    std = np.maximum(before.beta_std[:nb], 1e-300)
    names = before.base.base_names(max_terms=1)
    order = np.argsort(-np.abs(d))[:top]
    moved = "; ".join(
        f"[{names[i]}] {before.beta_b[i]:.4g} -> {after.beta_b[i]:.4g} ({abs(d[i]) / std[i]:.2g} sigma)" for i in order
    )
    loose = [i for i in order if abs(d[i]) <= 3.0 * std[i]]
    why = (
        "these moves are within 3 standard deviations of the estimate: the data do not determine these "
        "combinations, and the projection picks physically consistent values for them"
        if len(loose) == len(order)
        else "some move by more than 3 standard deviations: the least-squares estimate is physically impossible "
        "there (e.g. a negative mass or inertia); check the log (units, torque sign, friction) and the excitation"
    )
    note = f" ({before.base.note})" if before.base.note else ""
    return f"|delta beta_b| / |beta_b| = {rel:.3g}: the largest changes {moved}; {why}{note}"
