"""Base (minimal) inertial parameters: numerical reduction of the regressor by QR with column pivoting.

The joint torque regressor Y(q, dq, ddq) of an n-joint arm has 10 n columns (10 inertial parameters
per link, Pinocchio's order ``m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz`` about each joint frame), but
only n_b of them are linearly independent over all motions: some parameters never move a joint (e.g.
everything of link 1 except the inertia about its axis), others act only in fixed combinations (a
link's mass and first moments are lumped onto the previous joint). The standard numerical reduction
(Gautier 1990) stacks Y at random samples into W, factorises ``W P = Q R`` with column pivoting and reads
the rank n_b off the diagonal of R. With ``R = [[R1, R2], [0, 0]]`` (R1 of size n_b), the base
parameters are

    beta_b = pi_ind + K pi_dep,     K = R1^-1 R2,

where ``pi_ind`` are the n_b pivoted (independent) standard parameters and ``pi_dep`` the others, and
``Y pi == Y[:, ind] beta_b`` for every motion. The map back to standard parameters is not unique (any
change of pi_dep is absorbed); :meth:`BaseParameters.standard_from_base` returns the one nearest to a
nominal vector, which is what a controller loading an identified model uses.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.linalg

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.robots.robot_model import INERTIAL_PARAMETER_NAMES, RobotModel

__all__ = ["BaseParameters", "IllConditionedWarning", "compute_base_parameters"]

#: Relative threshold on |R_ii| / |R_00| below which a pivoted column counts as dependent. The
#: regressor columns of a 7-joint arm span about 4 decades in scale; genuinely dependent columns come out
#: at ~1e-13 relative (round-off), independent ones above ~1e-5, so 1e-8 separates them with margin.
DEFAULT_RANK_TOLERANCE = 1e-8

#: Fraction of the joint range used for the random samples (stay off the joint limits).
_RANGE_FRACTION = 0.9


class IllConditionedWarning(UserWarning):
    """A regressor is rank deficient or badly conditioned; the estimate may be unreliable."""


@dataclass(frozen=True)
class BaseParameters:
    """The base-parameter map of one robot: beta_b = pi[independent] + K pi[dependent].

    Attributes:
        n_joints: number of joints n.
        independent: indices (into the 10 n standard parameters) of the n_b base columns, in pivot order.
        dependent: indices of the other 10 n - n_b parameters.
        coefficients: K, (n_b, 10 n - n_b).
        standard_names: names of the 10 n standard parameters (``"m_<joint>"``, ``"Izz_<joint>"``, ...).
        rank_tolerance: the relative tolerance used to decide the rank.
        diagonal: |R_ii| / |R_00| of the pivoted QR (decreasing), the evidence for the rank.
    """

    n_joints: int
    independent: np.ndarray
    dependent: np.ndarray
    coefficients: np.ndarray
    standard_names: tuple[str, ...]
    rank_tolerance: float
    diagonal: np.ndarray

    @property
    def n_base(self) -> int:
        """n_b, the number of base parameters."""
        return int(self.independent.size)

    @property
    def n_standard(self) -> int:
        """10 n, the number of standard inertial parameters."""
        return 10 * self.n_joints

    # ------------------------------------------------------------------ maps
    def base_from_standard(self, standard: npt.ArrayLike) -> np.ndarray:
        """beta_b = pi_ind + K pi_dep for a (10 n,) standard parameter vector."""
        pi = self._check_standard(standard)
        return pi[self.independent] + self.coefficients @ pi[self.dependent]

    def standard_from_base(self, base: npt.ArrayLike, nominal: npt.ArrayLike | None = None) -> np.ndarray:
        """A standard vector pi with ``base_from_standard(pi) == base``, nearest (2-norm) to ``nominal``.

        Every such pi gives the same joint torques for every motion (hence the same M(q), C, g); the
        nearest-to-nominal one keeps the unidentifiable parts at their nominal values and spreads the
        change over each identifiable combination, so masses stay close to the nominal ones. Without a
        nominal vector it is the minimum-norm solution.
        """
        beta = np.asarray(base, dtype=float).reshape(-1)
        if beta.size != self.n_base:
            raise IdentificationError(f"expected {self.n_base} base parameters; got {beta.size}")
        pi0 = np.zeros(self.n_standard) if nominal is None else self._check_standard(nominal)
        A = self.matrix()
        residual = beta - A @ pi0
        return pi0 + A.T @ np.linalg.solve(A @ A.T, residual)

    def matrix(self) -> np.ndarray:
        """The (n_b, 10 n) matrix A with beta_b = A pi."""
        A = np.zeros((self.n_base, self.n_standard))
        A[np.arange(self.n_base), self.independent] = 1.0
        A[:, self.dependent] = self.coefficients
        return A

    def select(self, regressor: np.ndarray) -> np.ndarray:
        """The base regressor: the independent columns of a full regressor (..., 10 n) -> (..., n_b)."""
        return regressor[..., self.independent]

    def base_names(self, *, tol: float = 1e-10, max_terms: int = 6) -> list[str]:
        """Human-readable combinations, e.g. ``"Izz_j1 + 1 Iyy_j2 + 0.0961 m_j3 + ..."``."""
        out = []
        for r, col in enumerate(self.independent):
            terms = [self.standard_names[col]]
            coef = self.coefficients[r]
            order = np.argsort(-np.abs(coef))
            extra = [(coef[k], self.standard_names[self.dependent[k]]) for k in order if abs(coef[k]) > tol]
            for c, name in extra[:max_terms]:
                terms.append(f"{'+' if c > 0 else '-'} {abs(c):.4g} {name}")
            if len(extra) > max_terms:
                terms.append(f"+ ... ({len(extra) - max_terms} more)")
            out.append(" ".join(terms))
        return out

    def explain(self) -> str:
        """Why 10 n parameters reduce to n_b: per link, how many are base columns, lumped or unidentifiable."""
        A = self.matrix()
        n = self.n_joints
        after = self.diagonal[self.n_base] if self.n_base < self.diagonal.size else 0.0
        lines = [
            f"{self.n_base} base parameters of {self.n_standard} standard ones "
            f"({self.n_standard - self.n_base} removed); the QR diagonal drops from "
            f"{self.diagonal[self.n_base - 1]:.2e} to {after:.2e} "
            f"(tolerance {self.rank_tolerance:.0e}).",
            "per link: base columns (kept as the representative of a combination) / lumped into a base "
            "combination of another column / no effect on any joint torque:",
        ]
        for j in range(n):
            cols = range(10 * j, 10 * j + 10)
            kept = [c for c in cols if c in set(self.independent.tolist())]
            none = [c for c in cols if c not in kept and not np.any(np.abs(A[:, c]) > 1e-10)]
            lumped = [c for c in cols if c not in kept and c not in none]

            def nm(cs: list[int]) -> str:
                return ", ".join(INERTIAL_PARAMETER_NAMES[c % 10] for c in cs) or "-"

            lines.append(
                f"  link {j + 1}: {len(kept):2d} base ({nm(kept)}); {len(lumped)} lumped ({nm(lumped)}); "
                f"{len(none)} no effect ({nm(none)})"
            )
        return "\n".join(lines)

    def _check_standard(self, standard: npt.ArrayLike) -> np.ndarray:
        pi = np.asarray(standard, dtype=float).reshape(-1)
        if pi.size != self.n_standard:
            raise IdentificationError(
                f"expected {self.n_standard} standard inertial parameters (10 per joint); got {pi.size}"
            )
        return pi

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, object]:
        """JSON-ready description."""
        return {
            "n_joints": self.n_joints,
            "independent": self.independent.tolist(),
            "dependent": self.dependent.tolist(),
            "coefficients": self.coefficients.tolist(),
            "standard_names": list(self.standard_names),
            "rank_tolerance": self.rank_tolerance,
            "diagonal": self.diagonal.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> BaseParameters:
        """Inverse of :meth:`to_dict`."""
        try:
            n = int(d["n_joints"])  # type: ignore[call-overload]
            ind = np.asarray(d["independent"], dtype=int)
            dep = np.asarray(d["dependent"], dtype=int)
            K = np.asarray(d["coefficients"], dtype=float).reshape(ind.size, dep.size)
            names = tuple(str(x) for x in d["standard_names"])  # type: ignore[attr-defined]
            tol = float(d.get("rank_tolerance", DEFAULT_RANK_TOLERANCE))  # type: ignore[arg-type]
            diag = np.asarray(d.get("diagonal", []), dtype=float)
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed base-parameter description: {e}") from e
        if sorted(np.concatenate([ind, dep]).tolist()) != list(range(10 * n)):
            raise IdentificationError(
                f"malformed base-parameter description: independent + dependent indices must cover 0..{10 * n - 1}"
            )
        return cls(n, ind, dep, K, names, tol, diag)


def random_samples(
    robot: RobotModel, n_samples: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random (q, dq, ddq) inside the joint range (joints without finite limits: [-pi, pi])."""
    lo, hi = robot.lower_limit, robot.upper_limit
    bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo) | (np.abs(hi - lo) > 1e6)
    lo = np.where(bad, -np.pi, lo)
    hi = np.where(bad, np.pi, hi)
    mid, half = 0.5 * (lo + hi), 0.5 * _RANGE_FRACTION * (hi - lo)
    q = mid + half * rng.uniform(-1.0, 1.0, (n_samples, robot.n))
    dq = rng.normal(0.0, 1.0, (n_samples, robot.n))
    ddq = rng.normal(0.0, 3.0, (n_samples, robot.n))
    return q, dq, ddq


def compute_base_parameters(
    robot: RobotModel,
    *,
    n_samples: int = 300,
    seed: int = 0,
    rank_tolerance: float = DEFAULT_RANK_TOLERANCE,
) -> BaseParameters:
    """Numerical base-parameter reduction of ``robot``'s regressor (QR with column pivoting).

    Args:
        robot: the arm (only its kinematics and gravity direction matter).
        n_samples: random (q, dq, ddq) samples stacked into W ((n_samples n) x 10 n); a few times
            10 n / n rows are enough, more only cost time.
        seed: seed of the sampler.
        rank_tolerance: columns with |R_ii| <= rank_tolerance |R_00| are dependent.

    Raises:
        IdentificationError: the regressor is zero (no parameter moves any joint).
    """
    rng = np.random.default_rng(seed)
    q, dq, ddq = random_samples(robot, n_samples, rng)
    W = BatchRegressor(robot).compute_regressor(q, dq, ddq).reshape(-1, 10 * robot.n)
    # columns that are zero up to round-off: parameters with no effect on any joint torque
    norms = np.linalg.norm(W, axis=0)
    if not np.any(norms > 0):
        raise IdentificationError(f"the regressor of {robot.name!r} is zero: no parameter moves any joint")
    nonzero = np.flatnonzero(norms > rank_tolerance * norms.max())
    zero = np.flatnonzero(norms <= rank_tolerance * norms.max())
    # scale the others to unit norm so the pivoting compares directions, not units
    Ws = W[:, nonzero] / norms[nonzero]
    _, R, perm = scipy.linalg.qr(Ws, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    rel = diag / diag[0]
    nb = int(np.sum(rel > rank_tolerance))
    ind_s, dep_s = perm[:nb], perm[nb:]
    # in scaled coordinates: beta_s = pi_s[ind] + K_s pi_s[dep]; undo the scaling (pi_s = norm * pi)
    K_s = scipy.linalg.solve_triangular(R[:nb, :nb], R[:nb, nb:]) if dep_s.size else np.zeros((nb, 0))
    scale = norms[nonzero]
    K_dep = K_s * scale[dep_s][None, :] / scale[ind_s][:, None]
    ind = nonzero[ind_s]
    dep = np.concatenate([nonzero[dep_s], zero])
    K = np.hstack([K_dep, np.zeros((nb, zero.size))])
    K[np.abs(K) < 1e-12] = 0.0
    rel = np.concatenate([rel, np.zeros(zero.size)])
    names = tuple(robot.inertial_parameter_names())
    return BaseParameters(robot.n, ind.copy(), dep.copy(), K, names, float(rank_tolerance), rel)


def condition_number(matrix: np.ndarray) -> float:
    """2-norm condition number sigma_max / sigma_min of a tall matrix (inf if rank deficient)."""
    s = np.linalg.svd(matrix, compute_uv=False)
    if s.size == 0 or s[-1] <= s[0] * np.finfo(float).eps * max(matrix.shape):
        return float("inf")
    return float(s[0] / s[-1])


def warn_if_ill_conditioned(cond: float, what: str, limit: float, rank_deficiency: int = 0) -> None:
    """Warn (:class:`IllConditionedWarning`) when ``cond`` exceeds ``limit``, naming the condition number."""
    if rank_deficiency or not np.isfinite(cond):
        lost = f"{rank_deficiency} parameter combination(s)" if rank_deficiency else "some parameters"
        warnings.warn(
            f"{what} is rank deficient (condition number {cond:.3g}): {lost} not excited by the data; "
            "their estimate is arbitrary (use a richer trajectory or fewer parameters)",
            IllConditionedWarning,
            stacklevel=3,
        )
    elif cond > limit:
        warnings.warn(
            f"{what} is ill-conditioned (condition number {cond:.3g} > {limit:.3g}): the estimate is "
            "sensitive to noise (use an optimized excitation trajectory, see reflexarm excite)",
            IllConditionedWarning,
            stacklevel=3,
        )
