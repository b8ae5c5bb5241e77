"""From the normal equations of (19) to the result (the second half of
:func:`~reflexarm.ident.estimation.identify.identify_dynamics`): the wrist wrench settled, the weights of
Sigma, the solve (18), the parameter statistics, the friction follow-up and the
:class:`~reflexarm.ident.estimation.result.DynamicsIdentification`.

Everything here reads only the accumulated normal equations (and the row counts), never the rows, so a
log streamed block by block and a log held whole give the same result.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from reflexarm.errors import IdentificationError, NonFiniteEstimateError
from reflexarm.ident.estimation._regression import RegressionProblem
from reflexarm.ident.estimation._weighted_least_squares import _GramAccumulator, _Solution
from reflexarm.ident.estimation.base_parameters import warn_if_ill_conditioned
from reflexarm.ident.estimation.inertia_determinacy import assess_inertia_determinacy, warn_if_poorly_determined
from reflexarm.ident.estimation.result import DynamicsIdentification
from reflexarm.ident.estimation.wrist_wrench import WristWrenchDecision, decide_wrist_wrench
from reflexarm.ident.friction.parameters import FrictionParameters, check_friction_against_robot, format_joints
from reflexarm.logs.bounds import BadSample

#: The rows that stand out most, asked for only when a result is not finite (they may need the data again).
Suspects = Callable[[], list[BadSample]]


@dataclass(frozen=True)
class _Fit:
    sol: _Solution
    sigma2: np.ndarray
    std: np.ndarray
    s2: float
    residual_rms: np.ndarray


def estimate(
    pb: RegressionProblem,
    *,
    condition_limit: float,
    row_correlation: float,
    suspects: Suspects,
    has_any_wrench: bool,
) -> DynamicsIdentification:
    """Settle the wrench, weight, solve and build the result from ``pb``'s normal equations.

    ``row_correlation``: :func:`~reflexarm.ident.estimation.inertia_determinacy.filtered_rows_factor` of the logs;
    ``has_any_wrench``: some log has a wrist wrench (said in a note when it is left out as asked).
    """
    import time

    acc = pb.acc
    refuse_non_finite({"entries of the information matrix": acc.G}, suspects)
    if np.any(acc.rows == 0):  # only min_speed removes rows: no equation of the joint is left
        empty = tuple(int(j) for j in np.flatnonzero(acc.rows == 0))
        raise IdentificationError(
            f"joint(s) {format_joints(empty, pb.robot.joint_names)}: no sample left with |dq_j| >= min_speed = "
            f"{pb.min_speed:g} rad/s in {pb.total:,} samples; their torque would not enter the fit. Lower min_speed or "
            "log motion of these joints"
        )
    clock = time.perf_counter()
    notes: list[str] = [] if pb.known.is_zero else [pb.known.describe()]
    if pb.has_wrench:
        acc, decision = _settle_wrench(acc, pb.p, pb.wrench, row_correlation)
        notes.append(decision.reason)
    elif has_any_wrench:
        notes.append("wrist wrench left out as asked (wrench='exclude')")
    fit = _solve(pb, acc, notes, suspects)
    pb.t_solve += time.perf_counter() - clock
    what = f"the identification regressor ({pb.p} parameters, {int(acc.rows.max()):,} samples)"
    warn_if_ill_conditioned(fit.sol.condition_number, what, condition_limit, fit.sol.rank_deficiency)
    if fit.sol.rank_deficiency:
        notes.append(
            f"rank deficient by {fit.sol.rank_deficiency}: the unexcited parameter combinations got the minimum-norm "
            "estimate (in column-normalised coordinates)"
        )
    if pb.min_speed > 0:
        notes.append(
            f"rows with |dq_j| < {pb.min_speed:g} rad/s left out: "
            + ", ".join(f"{100 * (1 - r / pb.total):.0f} %" for r in acc.rows)
            + " of each joint's samples"
        )
    return _result(pb, fit, notes, row_correlation)


def _solve(pb: RegressionProblem, acc: _GramAccumulator, notes: list[str], suspects: Suspects) -> _Fit:
    """Sigma (given, from an unweighted pass, or I), the weighted solve (18) and the parameter statistics."""
    n, p = pb.n, pb.p
    if pb.given_variance is not None:
        sigma2 = pb.given_variance
        notes.append(
            "Sigma from the given per-joint noise variances: " + ", ".join(f"{s:.3g}" for s in sigma2) + " Nm^2"
        )
    elif pb.noise_variance is None:
        sigma2 = np.ones(n)
        notes.append("unweighted least squares (Sigma = I)")
    else:
        # per-joint residual variance of an unweighted fit -> Sigma of (18)
        x0 = acc.solve(np.ones(n)).x
        sigma2 = np.maximum(acc.residual_ss(x0) / np.maximum(acc.rows - p / n, 1.0), 1e-12)
        refuse_non_finite({"unweighted parameters": x0, "noise variances": sigma2}, suspects)
        notes.append(
            "Sigma from the per-joint residual variances of an unweighted pass: "
            + ", ".join(f"{s:.3g}" for s in sigma2)
            + " Nm^2"
        )
    sol = acc.solve(1.0 / np.sqrt(sigma2))
    # parameter standard deviations: s^2 (F^T W F)^+ with s^2 the weighted residual variance
    dof = max(int(acc.rows.sum()) - p, 1)
    s2 = sol.residual_norm**2 / dof
    std = np.sqrt(np.maximum(s2 * np.diag(sol.covariance), 0.0))
    residual_rms = np.sqrt(acc.residual_ss(sol.x) / np.maximum(acc.rows, 1))
    refuse_non_finite({"parameters": sol.x, "standard deviations": std, "residual RMS": residual_rms}, suspects)
    return _Fit(sol, sigma2, std, s2, residual_rms)


def _friction(pb: RegressionProblem, x: np.ndarray, std: np.ndarray) -> FrictionParameters:
    """The friction of the result: the given one, with the estimated joints (and offsets) from ``x``; the
    estimated values held against the robot's (a warning when implausible)."""
    n, nb, n_fe, fixed = pb.n, pb.nb, pb.n_fe, pb.fixed
    fe = np.asarray(pb.fric_est, dtype=int)
    viscous = np.zeros(n) if fixed is None else fixed.viscous.copy()  # combined: every entry estimated below
    coulomb = np.zeros(n) if fixed is None else fixed.coulomb.copy()
    viscous[fe], coulomb[fe] = x[nb : nb + n_fe], x[nb + n_fe : nb + 2 * n_fe]
    fr = FrictionParameters(viscous, coulomb, None if fixed is None else fixed.offset)
    if pb.est_offset:
        fr = replace(fr, offset=x[nb + 2 * n_fe : nb + 2 * n_fe + n])
    if n_fe:
        v_std, c_std = np.zeros(n), np.zeros(n)
        v_std[fe], c_std[fe] = std[nb : nb + n_fe], std[nb + n_fe : nb + 2 * n_fe]
        check_friction_against_robot(
            fr,
            pb.robot,
            joints=pb.fric_est,
            std=FrictionParameters(v_std, c_std),
            source=f"{pb.method} identification",
            stacklevel=7,
        )
    return fr


def _result(pb: RegressionProblem, fit: _Fit, notes: list[str], row_correlation: float) -> DynamicsIdentification:
    robot, nb, sol = pb.robot, pb.nb, fit.sol
    beta_b = sol.x[:nb]
    # how well M(q) is determined, from the covariance s^2 (F^T W F)^+ of beta_b (inertia_determinacy)
    determinacy = assess_inertia_determinacy(
        robot, pb.base, beta_b, fit.s2 * sol.covariance[:nb, :nb], armature=pb.known.armature,
        row_correlation=row_correlation,
    )  # fmt: skip
    warn_if_poorly_determined(determinacy, f"{pb.method} identification", stacklevel=6)
    fr = _friction(pb, sol.x, fit.std)
    if pb.method == "sequential" and pb.n_fe:
        notes.append(
            f"the given friction has none for joint(s) {format_joints(pb.fric_est, robot.joint_names)} (not "
            f"identified): their d_v, mu_C were estimated with beta_b ({nb} + {2 * pb.n_fe} unknowns); the other "
            "joints' friction is the given one (eq. 16)"
        )
    return DynamicsIdentification(
        method=pb.method,
        robot_name=robot.name,
        joint_names=tuple(robot.joint_names),
        base=pb.base,
        beta_b=beta_b,
        friction=fr,
        beta_std=fit.std,
        noise_variance=fit.sigma2,
        condition_number=sol.condition_number,
        n_samples=pb.total,
        residual_rms=fit.residual_rms,
        notes=tuple(notes),
        timings={"regressor_s": pb.t_reg, "solve_s": pb.t_solve},
        information=sol.information,
        known_terms=pb.known,
        friction_estimated=pb.fric_est,
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


def refuse_non_finite(values: dict[str, np.ndarray], suspects: Suspects) -> None:
    """Raise :class:`NonFiniteEstimateError` naming the likely bad rows if any of ``values`` is NaN/inf."""
    bad = {name: int(np.sum(~np.isfinite(v))) for name, v in values.items() if not np.all(np.isfinite(v))}
    if not bad:
        return
    found = suspects()
    what = ", ".join(f"{k} of {values[name].size} {name}" for name, k in bad.items())
    if found:
        listed = "; ".join(f"{s.source} {s} (its column's 99th percentile {s.reference:.3g})" for s in found)
        cause = f"the rows that stand out most from their columns (likely bad rows): {listed}. Remove or repair them"
    else:
        cause = "no row stands out from its column; check the given noise variances (tiny ones overflow the weights)"
    raise NonFiniteEstimateError(
        f"identification gave non-finite results ({what}): the weighted least-squares problem overflowed; {cause}",
        tuple(found),
    )
