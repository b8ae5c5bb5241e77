"""Physically consistent base parameters: the nearest realisable beta_b in the metric of the fit.

Least squares returns the beta_b that fits the data best, with no regard for physics. When a data set
carries effects the model lacks (sticking at velocity reversals, Stribeck friction) or the excitation
barely reaches some parameters (the light wrist links of the Atlas arm), the estimate can correspond to
no real set of rigid bodies: M(q) is then not positive definite somewhere in the joint range, and a
controller that factorises M(q) fails there.

A standard parameter vector pi is physically consistent when each link's 4x4 pseudo-inertia

    J = [[Sigma, h], [h^T, m]],   Sigma = tr(I)/2 * 1 - I,  h = m c,

(I about the link frame origin) is positive semidefinite (Wensing, Kim, Slotine 2017); then M(q) is
positive definite for every q. :func:`project_physically_consistent` finds, among all consistent pi,
the one whose base parameters A pi are nearest to the estimate in the metric of the fit,

    min_pi (A pi - beta_hat)^T H (A pi - beta_hat)   s.t.  J_k(pi) >= 0 for every link k,

where H is the information matrix F^T Sigma^-1 F (for the combined method the friction parameters are
eliminated: H is the Schur complement, and the friction follows the change of beta_b). The constraint is
built in by writing each J_k = L_k L_k^T with L_k lower triangular (10 numbers, like the 10 inertial
parameters), and the problem is solved by ``scipy.optimize.least_squares`` from the robot file's
nominal (consistent) inertias. The objective is the increase of the weighted residual sum of squares
of the fit, so the result says exactly how much fit quality physics costs.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.optimize

from reflexarm.errors import IdentificationError
from reflexarm.ident._blas_threads import DEFAULT_BLAS_THREADS, blas_threads
from reflexarm.ident.estimation.identify import DynamicsIdentification, FrictionParameters, mass_matrix_margin
from reflexarm.robots.robot_model import RobotModel

__all__ = ["project_physically_consistent", "pseudo_inertia", "standard_from_pseudo_inertia"]

_TRIL = np.tril_indices(4)
#: Each link's pseudo-inertia is kept above this fraction of the smallest eigenvalue of its nominal one.
MIN_EIGENVALUE_FRACTION = 1e-3


def pseudo_inertia(link_parameters: np.ndarray) -> np.ndarray:
    """4x4 pseudo-inertia of one link from its 10 parameters (m, m c, Ixx, Ixy, Iyy, Ixz, Iyz, Izz)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(link_parameters, dtype=float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = (hx, hy, hz)
    J[3, 3] = m
    return J


def standard_from_pseudo_inertia(J: np.ndarray) -> np.ndarray:
    """The 10 link parameters of 4x4 pseudo-inertia(s) (..., 4, 4) (inverse of :func:`pseudo_inertia`)."""
    S = J[..., :3, :3]
    tr = S[..., 0, 0] + S[..., 1, 1] + S[..., 2, 2]
    return np.stack(
        [J[..., 3, 3], J[..., 0, 3], J[..., 1, 3], J[..., 2, 3], tr - S[..., 0, 0], -S[..., 0, 1], tr - S[..., 1, 1],
         -S[..., 0, 2], -S[..., 1, 2], tr - S[..., 2, 2]],
        axis=-1,
    )  # fmt: skip


#: One-hot 4x4 matrices of the lower-triangular entries (the factor's coordinates).
_UNIT = np.zeros((10, 4, 4))
_UNIT[np.arange(10), _TRIL[0], _TRIL[1]] = 1.0


def _factors(x: np.ndarray, n: int) -> np.ndarray:
    L = np.zeros((n, 4, 4))
    L[:, _TRIL[0], _TRIL[1]] = x.reshape(n, 10)
    return L


def project_physically_consistent(
    result: DynamicsIdentification,
    robot: RobotModel,
    *,
    max_nfev: int = 3000,
    threads: int | None = DEFAULT_BLAS_THREADS,
    fixed_parameters: np.ndarray | None = None,
) -> DynamicsIdentification:
    """The nearest physically consistent identification (see the module docstring).

    Args:
        result: an identification (with its information matrix).
        robot: the robot; its nominal inertias start the search (made strictly consistent if needed).
        max_nfev: evaluation budget of the solver.
        threads: BLAS threads (default 1, as :func:`~reflexarm.ident.identify_dynamics`); None: as configured.
        fixed_parameters: (10 n,) a known part of each joint's lumped link parameters that is not changed
            (e.g. a locked gripper's links, whose inertias stay the file's): the pseudo-inertia constraint
            applies to the rest, pi - fixed_parameters, and the returned physical parameters include it.

    Returns:
        A copy of ``result`` with the projected beta_b (and, for the combined method, the friction moved
        accordingly), ``physical_parameters`` set to the consistent standard vector, and a note with
        the increase of the weighted residual sum of squares.

    Raises:
        IdentificationError: the result has no information matrix (e.g. read from an old file), has
            NaN/inf parameters or information, or the projection fails numerically (the solver's error is
            chained); never a raw numpy/scipy error.
    """
    if result.information is None:
        raise IdentificationError("the identification has no information matrix; re-run identify_dynamics")
    checked = {
        "beta_b": result.beta_b,
        "information matrix": result.information,
        "friction": result.friction.parameters(),
        "nominal inertial parameters": robot.inertial_parameters(),
    }
    for name, value in checked.items():
        v = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(v)):
            raise IdentificationError(
                f"cannot project a {result.method} identification with non-finite {name} "
                f"({int(np.sum(~np.isfinite(v)))} of {v.size} entries NaN/inf) onto consistent parameters; "
                "re-identify on a clean log (identify_dynamics names the likely bad rows)"
            )
    try:
        with blas_threads(threads):
            return _project(result, robot, max_nfev, fixed_parameters)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as e:
        raise IdentificationError(
            f"projecting the {result.method} identification onto physically consistent parameters failed: "
            f"{type(e).__name__}: {e}"
        ) from e


def _metric(result: DynamicsIdentification) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(H_eff, K, R): the information of beta_b with the friction (and offset) parameters eliminated (Schur
    complement; d(friction) = -K d(beta), K None without them) and its scaled Cholesky factor R^T R = H_eff."""
    assert result.information is not None  # checked by the caller
    nb = result.base.n_base
    H = np.asarray(result.information, dtype=float)
    if nb < H.shape[0]:
        Hbb, Hbf, Hff = H[:nb, :nb], H[:nb, nb:], H[nb:, nb:]
        K = np.linalg.solve(Hff, Hbf.T)
        H_eff = Hbb - Hbf @ K
    else:
        K = None
        H_eff = H
    H_eff = 0.5 * (H_eff + H_eff.T)
    scale = np.sqrt(np.maximum(np.diag(H_eff), 1e-300))
    R = np.linalg.cholesky(H_eff / np.outer(scale, scale) + 1e-14 * np.eye(nb)).T * scale[None, :]
    return H_eff, K, R


def _start(robot: RobotModel, fixed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x0, pi_eps): the nominal links' Cholesky factors and the parameters of the eigenvalue floors.

    J_k = L_k L_k^T + eps_k 1, eps_k = MIN_EIGENVALUE_FRACTION * lambda_min(nominal J_k): every link keeps a
    strictly positive definite pseudo-inertia, so M(q) stays positive definite (a link may not collapse to a
    point or a rod on a joint axis)."""
    n = robot.n
    x0 = np.empty(10 * n)
    pi0 = robot.inertial_parameters() - fixed
    eps = np.empty(n)
    for k in range(n):
        J = pseudo_inertia(pi0[10 * k : 10 * k + 10])
        ev = np.linalg.eigvalsh(J)
        floor = 1e-6 * max(ev[-1], 1e-9)
        if ev[0] < floor:  # an inconsistent or degenerate nominal link: start from a consistent neighbour
            J = J + (floor - ev[0]) * np.eye(4)
            ev = np.linalg.eigvalsh(J)
        eps[k] = MIN_EIGENVALUE_FRACTION * ev[0]
        x0[10 * k : 10 * k + 10] = np.linalg.cholesky(J - eps[k] * np.eye(4))[_TRIL]
    pi_eps = standard_from_pseudo_inertia(eps[:, None, None] * np.eye(4)[None]).reshape(-1) + fixed
    return x0, pi_eps


def _follow_friction(result: DynamicsIdentification, K: np.ndarray | None, d_beta: np.ndarray) -> FrictionParameters:
    """The estimated friction (and offsets) moved with beta_b: d(friction) = -K d(beta)."""
    friction = result.friction
    if K is None:
        return friction
    n = result.base.n_joints
    fe = list(result.estimated_friction_joints)
    m = len(fe)
    f = np.r_[friction.viscous[fe], friction.coulomb[fe]]
    estimated_offset = friction.offset is not None and K.shape[0] == 2 * m + n
    if estimated_offset:
        f = np.r_[f, friction.offset]
    f = f - K @ d_beta
    viscous, coulomb = friction.viscous.copy(), friction.coulomb.copy()
    viscous[fe], coulomb[fe] = f[:m], f[m : 2 * m]
    return FrictionParameters(viscous, coulomb, f[2 * m : 2 * m + n] if estimated_offset else friction.offset)


def _project(
    result: DynamicsIdentification, robot: RobotModel, max_nfev: int, fixed: np.ndarray | None
) -> DynamicsIdentification:
    n = result.base.n_joints
    H_eff, K, R = _metric(result)
    A = result.base.matrix()
    beta_hat = result.beta_b
    fixed = np.zeros(10 * n) if fixed is None else np.asarray(fixed, dtype=float).reshape(10 * n)
    x0, pi_eps = _start(robot, fixed)
    RA = R @ A
    target = R @ beta_hat - RA @ pi_eps

    def pi_of(x: np.ndarray) -> np.ndarray:
        L = _factors(x, n)
        return standard_from_pseudo_inertia(L @ np.swapaxes(L, 1, 2)).reshape(-1) + pi_eps

    def residual(x: np.ndarray) -> np.ndarray:
        L = _factors(x, n)
        return RA @ standard_from_pseudo_inertia(L @ np.swapaxes(L, 1, 2)).reshape(-1) - target

    def jacobian(x: np.ndarray) -> np.ndarray:
        # pi is linear in J = L L^T: d pi = P(dL L^T + L dL^T), one column per entry of L
        L = _factors(x, n)  # (n, 4, 4)
        EL = np.einsum("eij,nkj->neik", _UNIT, L)  # E_e L^T per link: (n, 10, 4, 4)
        dpi = standard_from_pseudo_inertia(EL + np.swapaxes(EL, 2, 3))  # (n, 10 entries, 10 params)
        D = np.zeros((10 * n, 10 * n))
        for k in range(n):
            D[10 * k : 10 * k + 10, 10 * k : 10 * k + 10] = dpi[k].T
        return RA @ D

    sol = scipy.optimize.least_squares(residual, x0, jac=jacobian, method="trf", max_nfev=max_nfev)
    pi = pi_of(sol.x)
    beta = A @ pi
    d_beta = beta - beta_hat
    cost = float(d_beta @ H_eff @ d_beta)
    rel_change = float(np.linalg.norm(d_beta)) / max(float(np.linalg.norm(beta_hat)), 1e-300)
    rss = float(np.sum(result.residual_rms**2 / np.maximum(result.noise_variance, 1e-300))) * result.n_samples
    return replace(
        result,
        beta_b=beta,
        friction=_follow_friction(result, K, d_beta),
        physical_parameters=pi,
        notes=result.notes
        + (
            f"projected onto physically consistent parameters (pseudo-inertias positive definite): weighted "
            f"residual sum of squares +{cost:.4g} ({100 * cost / max(rss, 1e-300):.3g} % of {rss:.4g}); "
            f"|delta beta_b| / |beta_b| = {rel_change:.3g}",
        ),
    )


def is_physically_consistent(result: DynamicsIdentification, robot: RobotModel) -> bool:
    """True if the mass matrix of ``result`` is positive definite at sampled configurations of the range."""
    import warnings

    from reflexarm.ident.estimation.identify import PhysicalConsistencyWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PhysicalConsistencyWarning)
        return mass_matrix_margin(result.to_robot_model(robot)) > 0
