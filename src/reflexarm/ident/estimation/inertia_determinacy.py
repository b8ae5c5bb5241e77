"""How well the data determine the identified mass matrix M(q), from the parameter covariance alone.

A log dominated by gravity can give a model whose torque predictions pass validation while its M(q) is
poor (the acceleration columns of the regressor were hardly excited). Disturbance compensation needs
M(q) (the observer's generalized momentum p = M(q) dq), so a poorly determined M(q) makes it risky.
No true model is needed to see this: M(q) is linear in the base parameters,

    M(q) = sum_k beta_k M_k(q) + diag(I_a),

where column j of M_k(q) is the base regressor at (q, dq = 0, ddq = e_j) minus the one at (q, 0, 0)
(this removes gravity exactly, the regressor being linear in ddq), and I_a is the file's armature (given,
not identified). The covariance Cov(beta) of the weighted least squares (s^2 (F^T W F)^-1, eq. (18))
therefore gives the covariance of M(q).

The measure (one definition, used everywhere here): at a posture q, with M_hat(q) the identified mass matrix,

    u(q) = sqrt( E ||dM(q)||_F^2 ) / ||M_hat(q)||_F = sqrt( sum_kl Cov_kl <M_k(q), M_l(q)>_F ) / ||M_hat(q)||_F,

dM = sum_k dbeta_k M_k(q), dbeta ~ N(0, Cov(beta)): the 1-sigma relative error of M(q) in the Frobenius
norm, the measure of the relative M(q) errors of issue 9's finding F8. It is reported as median and max over
a fixed, seeded set of postures uniform in 90 % of the joint range
(:func:`~reflexarm.ident.estimation.base_parameters.random_samples`, seed 0, 200 postures), with the posture of the max.

Filtered logs: Cov(beta) = s^2 (F^T W F)^-1 assumes independent rows. A log low-passed at f_c (the
identification's preprocessing, 10 Hz by default) sampled at f_s has errors correlated over about
f_s / (2 f_c) rows, so that formula underestimates the variance by that factor (exact for white noise before
the filter and regressors below f_c). Given the cutoff, the covariance is scaled by max(1, f_s / (2 f_c))
(:func:`filtered_rows_factor`; ``row_correlation`` in the result). On F8's iiwa14 logs (10 Hz, 1 kHz: factor
50, std x 7.1) the corrected u is still 2.3-4.5 times below the M(q) error of the least-squares estimate
against the file (random start: u median/max 10.4 %/24.9 %, error 46.8 %/88.7 %; optimized: 2.1 %/4.1 %,
error 5.2 %/9.4 %): unmodelled, non-white errors are not in it, so u is a lower bound.

Overstated by Coulomb friction in low-passed torques: the filter smooths the friction step at a velocity
reversal, sgn(dq) in the regressor does not, and the difference (a blip at each reversal, of the size of
mu_C) counts as noise in s^2. On the Atlas arm with exact data (tests/test_ident_cli.py, sequential, 10 Hz)
it gives u median/max 17.7 %/50.0 % while the estimate is exact (error < 0.05 %); leaving out the rows with
|dq| < 0.1 rad/s (``min_speed``, ``--min-speed``) gives 1.3 %/3.5 % (error 0.3 %/1.2 %). The warning says so.

Threshold (:data:`DEFAULT_MAX_RELATIVE_STD`, on the max over the postures): 0.15. In F8 (iiwa14) the model
whose M(q) was off by 8.7 % at worst (median 4.0 %) worked with disturbance compensation, the one off by
31.7 % at worst (median 13.9 %) diverged. At u_max = 0.15 a 2-sigma error (reached about 1 time in 20)
is 30 % at the worst posture, the size that diverged. Measured u_max on those two logs: 24.9 % (random
start, warned) and 4.1 % (optimized).

Not chosen: the spread of the generalized eigenvalues of (M, M_hat) (whitening by M_hat). Measured on the
UR-like arm (no armature, smallest eigenvalue of M 4.7e-4 kg m^2 at q = 0, the wrist), every excitation
tried (3-5 harmonics, one 10 s period, white torque noise 0.05-0.5 Nm) leaves that eigenvalue's relative
error near or above 100 % (M_hat often indefinite there) while the absolute torque it makes is below the noise; such a
measure would flag every model of such an arm. The Frobenius measure weights the directions by their
inertia, so it reports the heavy (shoulder, elbow) part the torque predictions rest on.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError, PoorlyDeterminedInertiaWarning
from reflexarm.ident.estimation.base_parameters import BaseParameters, random_samples
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DEFAULT_MAX_RELATIVE_STD",
    "InertiaDeterminacy",
    "assess_inertia_determinacy",
    "filtered_rows_factor",
    "mass_matrix_regressor",
    "warn_if_poorly_determined",
]

#: u_max above which disturbance compensation with the model is risky (see the module docstring).
DEFAULT_MAX_RELATIVE_STD = 0.15

#: Postures (uniform in 90 % of the joint range, seeded) over which u(q) is evaluated.
DEFAULT_POSTURES = 200


@dataclass(frozen=True)
class InertiaDeterminacy:
    """u(q) of the module docstring over a fixed set of postures.

    Attributes:
        median: median of u(q) over the postures (dimensionless; 0.1 = 10 %).
        max: its max.
        worst_posture: the posture of the max [rad or m], 0-based joint order.
        n_postures, seed: the posture set.
        threshold: the limit :func:`warn_if_poorly_determined` uses.
        row_correlation: the factor the covariance was scaled by for correlated (low-passed) rows.
    """

    median: float
    max: float
    worst_posture: np.ndarray
    n_postures: int
    seed: int
    threshold: float = DEFAULT_MAX_RELATIVE_STD
    row_correlation: float = 1.0

    @property
    def poorly_determined(self) -> bool:
        return not self.max <= self.threshold

    def to_dict(self) -> dict[str, object]:
        """JSON-ready (inf written as None)."""
        return {
            "definition": "u(q) = sqrt(E||dM(q)||_F^2) / ||M_hat(q)||_F, dbeta ~ N(0, Cov(beta_b)): 1-sigma "
            "relative error of M(q) from the least-squares covariance, over seeded postures in the joint range",
            "median": _finite_or_none(self.median),
            "max": _finite_or_none(self.max),
            "worst_posture": self.worst_posture.tolist(),
            "n_postures": self.n_postures,
            "seed": self.seed,
            "threshold": self.threshold,
            "poorly_determined": self.poorly_determined,
            "row_correlation": self.row_correlation,
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> InertiaDeterminacy:
        """Inverse of :meth:`to_dict` (None -> inf)."""

        def num(key: str) -> float:
            v = d[key]
            return float("inf") if v is None else float(v)  # type: ignore[arg-type]

        return cls(
            num("median"),
            num("max"),
            np.asarray(d["worst_posture"], dtype=float),
            int(d["n_postures"]),  # type: ignore[call-overload]
            int(d["seed"]),  # type: ignore[call-overload]
            num("threshold"),
            float(d.get("row_correlation", 1.0)),  # type: ignore[arg-type]
        )

    def posture_text(self) -> str:
        return ", ".join(f"{x:.2f}" for x in self.worst_posture)

    def describe(self) -> str:
        return (
            f"1-sigma relative uncertainty of M(q) (Frobenius, {self.n_postures} postures): "
            f"median {100 * self.median:.1f} %, max {100 * self.max:.1f} % at q = [{self.posture_text()}] "
            f"(limit {100 * self.threshold:.0f} %"
            + (f"; covariance x {self.row_correlation:.3g} for low-passed rows)" if self.row_correlation != 1 else ")")
        )


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def mass_matrix_regressor(robot: RobotModel, base: BaseParameters, q: npt.ArrayLike) -> np.ndarray:
    """M_k(q) for postures q (N, n): (N, n, n, n_b) with M(q) = YM @ beta_b (+ the file's armature)."""
    Q = np.atleast_2d(np.asarray(q, dtype=float))
    N, n = Q.shape
    reg = BatchRegressor(robot)
    # row block 0: ddq = 0 (gravity only); block 1 + j: ddq = e_j
    QQ = np.tile(Q, (n + 1, 1))
    DDQ = np.zeros((n + 1, N, n))
    DDQ[np.arange(1, n + 1), :, np.arange(n)] = 1.0
    Y = base.select(reg.compute_regressor(QQ, np.zeros_like(QQ), DDQ.reshape(-1, n))).reshape(n + 1, N, n, -1)
    cols = Y[1:] - Y[0][None]  # (j, N, i, k): entry (i, j) of M_k
    return cols.transpose(1, 2, 0, 3)


def assess_inertia_determinacy(
    robot: RobotModel,
    base: BaseParameters,
    beta_b: npt.ArrayLike,
    covariance: npt.ArrayLike,
    *,
    armature: npt.ArrayLike | None = None,
    n_postures: int = DEFAULT_POSTURES,
    seed: int = 0,
    threshold: float = DEFAULT_MAX_RELATIVE_STD,
    row_correlation: float = 1.0,
) -> InertiaDeterminacy:
    """u(q) (module docstring) of the identified beta_b with covariance ``covariance`` (n_b, n_b).

    Args:
        robot: the arm (kinematics).
        base: the base-parameter map of beta_b.
        beta_b: the identified base parameters.
        covariance: their covariance (the top-left n_b block of the estimate's covariance).
        armature: the file's rotor inertia per joint, part of M_hat (default 0).
        n_postures, seed: the posture set (uniform in 90 % of the joint range).
        threshold: the limit stored with the result.
        row_correlation: scale the covariance by this (correlated rows, see :func:`filtered_rows_factor`).
    """
    beta = np.asarray(beta_b, dtype=float).reshape(-1)
    C = float(row_correlation) * np.asarray(covariance, dtype=float)
    nb = base.n_base
    if beta.size != nb or C.shape != (nb, nb):
        raise IdentificationError(
            f"expected {nb} base parameters and a ({nb}, {nb}) covariance; got {beta.size} and {C.shape}"
        )
    q, _, _ = random_samples(robot, n_postures, np.random.default_rng(seed))
    YM = mass_matrix_regressor(robot, base, q)
    Mhat = YM @ beta
    if armature is not None:
        Mhat = Mhat + np.diag(np.asarray(armature, dtype=float).reshape(-1))[None]
    C = 0.5 * (C + C.T)
    flat = YM.reshape(n_postures, -1, nb)  # (N, n*n, n_b): entries of M_k(q)
    var = np.einsum("iak,kl,ial->i", flat, C, flat)  # E ||dM(q)||_F^2
    u = np.sqrt(np.maximum(var, 0.0)) / np.maximum(np.linalg.norm(Mhat, axis=(1, 2)), 1e-300)
    worst = int(np.argmax(u))
    return InertiaDeterminacy(
        float(np.median(u)), float(u[worst]), q[worst].copy(), n_postures, seed, threshold, float(row_correlation)
    )


def filtered_rows_factor(sample_periods: Sequence[float], cutoff_hz: float | None) -> float:
    """max(1, f_s / (2 f_c)) with f_s the fastest rate of ``sample_periods`` [s]: rows per independent error
    of a log low-passed at ``cutoff_hz`` (None: unfiltered, 1)."""
    if cutoff_hz is None:
        return 1.0
    if not cutoff_hz > 0:
        raise IdentificationError(f"filter cutoff must be positive [Hz]; got {cutoff_hz!r}")
    return max(1.0, 1.0 / (2.0 * cutoff_hz * min(sample_periods)))


def warn_if_poorly_determined(d: InertiaDeterminacy, what: str, *, stacklevel: int = 2) -> None:
    """Warn (:class:`~reflexarm.errors.PoorlyDeterminedInertiaWarning`) when ``d.max`` exceeds its threshold."""
    if not d.poorly_determined:
        return
    message = (
        f"{what}: the data determine M(q) poorly: {d.describe()}. The torque "
        "predictions (and validation) can still look good, since gravity dominates them, but disturbance "
        "compensation needs M(q) (the observer's p = M(q) dq) and may diverge with this model. Identify again "
        "from an optimized excitation ('reflexarm excite' without --maxiter 0) and/or a longer log (more periods). "
        "If the joints have Coulomb friction and the torques were low-passed, the smoothed friction step at velocity "
        "reversals inflates this number: check it with min_speed (--min-speed 0.1) first"
    )
    warnings.warn(
        PoorlyDeterminedInertiaWarning(message, median=d.median, max=d.max, worst_posture=d.worst_posture,
                                       threshold=d.threshold),
        stacklevel=stacklevel + 1,
    )  # fmt: skip
