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

from collections.abc import Sequence
from typing import Literal

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.ident._blas_threads import DEFAULT_BLAS_THREADS, blas_threads
from reflexarm.ident.estimation._estimate import estimate
from reflexarm.ident.estimation._regression import METHODS, check_logs, setup_problem
from reflexarm.ident.estimation.base_parameters import BaseParameters
from reflexarm.ident.estimation.inertia_determinacy import filtered_rows_factor
from reflexarm.ident.estimation.known_terms import KnownJointTerms  # noqa: F401  (tests patch it here)
from reflexarm.ident.estimation.result import (
    DynamicsIdentification,
    PhysicalConsistencyWarning,
    mass_matrix_margin,
    save_identification,
)
from reflexarm.ident.estimation.validation import TorqueValidation, validate_model
from reflexarm.ident.friction.parameters import FrictionParameters
from reflexarm.logs.plausibility import likely_bad_rows
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
    """:func:`identify_dynamics` with BLAS threads set: the rows of every log reduced to the normal equations
    (:mod:`._regression`), then weighted, solved and reported (:mod:`._estimate`)."""
    if method not in METHODS:
        raise IdentificationError(f"unknown identification method {method!r}; choose one of: {', '.join(METHODS)}")
    logs = [log] if isinstance(log, RobotLog) else list(log)
    if not logs:
        raise IdentificationError("no log given")
    check_logs(logs, robot, check_limits)
    has_any_wrench = any(lg.wrench is not None for lg in logs)
    pb = setup_problem(robot, method, friction, offset, noise_variance, base, min_speed, wrench, has_any_wrench)
    for lg in logs:
        pb.add_log(lg, lambda it, lg: _progress(it, progress, lg))
    return estimate(
        pb,
        condition_limit=condition_limit,
        row_correlation=filtered_rows_factor([float(np.median(np.diff(lg.t))) for lg in logs], filter_cutoff_hz),
        suspects=lambda: likely_bad_rows(logs),
        has_any_wrench=has_any_wrench,
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
