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

What the data can determine. The QR runs on the regressor's columns scaled to torques: each column times
a typical size of its parameter (the link's mass m, m l for first moments, m l^2 for inertias, l the
arm's mean joint-to-joint distance), so |R_ii| / |R_00| is the torque a combination adds, at typical
parameter sizes, relative to the largest. A combination below :data:`DEFAULT_RANK_TOLERANCE` is counted
as dependent: its torque is below what a torque measurement resolves. Such *near-dependent*
combinations come from axes that are nearly but not exactly aligned, e.g. a vendor file's
``rpy="3.1416 0 0"`` (pi rounded to 4 decimals) tilts a vertical first axis by 7.3e-6 rad and adds two
combinations 3e-6 below the largest: counting them gives 45 instead of 43 base parameters of a 7-DoF arm,
a regressor with condition number ~1e6 whatever the motion, and estimates dominated by noise. They are
counted as dependent, and :func:`compute_base_parameters` says so
(:class:`NearlyDependentWarning`, naming the joint whose axis is nearly aligned).
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

__all__ = ["BaseParameters", "IllConditionedWarning", "NearlyDependentWarning", "compute_base_parameters"]

#: Relative threshold on |R_ii| / |R_00| of the torque-scaled QR (see the module docstring) below which
#: a combination counts as dependent. Measured (300 samples, seed 0): the weakest genuine combination
#: is at 1.9e-3 (Panda), 4.5e-3 (Atlas), 7.5e-3 (UR-like), 9.6e-3 (Gen3-like), 1.4e-2 (iiwa14); exactly
#: dependent ones at <= 2e-15 (round-off); the two that a 3.1416 roll adds on the Gen3-like arm at 3e-6.
#: 1e-4 sits a decade and more from both. Its meaning: a torque sensor's noise of ~1 % of the largest
#: torque, averaged over a log of ~1e4 samples, resolves ~1e-4 of it; smaller contributions are noise.
DEFAULT_RANK_TOLERANCE = 1e-4
#: Relative |R_ii| / |R_00| at and below which a combination is dependent up to round-off (exactly
#: dependent in the arm's geometry): between this and the rank tolerance it is *nearly* dependent.
ROUND_OFF_TOLERANCE = 1e-10
#: Shortest length scale of the parameter sizes [m] (arms whose joints all coincide still get one).
_MIN_LENGTH_SCALE = 0.05
#: An axis within this angle [rad] of being parallel (to gravity or to the previous joint's axis) but not
#: within round-off of it is named as the nearly aligned one (0.01 rad: rounded rpy values and mounting
#: tolerances, well below any deliberate design angle).
_NEAR_ALIGNMENT = 1e-2

#: Fraction of the joint range used for the random samples (stay off the joint limits).
_RANGE_FRACTION = 0.9


class IllConditionedWarning(UserWarning):
    """A regressor is rank deficient or badly conditioned; the estimate may be unreliable."""


class NearlyDependentWarning(IllConditionedWarning):
    """Some regressor combinations are nearly, not exactly, dependent (an axis nearly aligned) and were
    counted as dependent.

    Attributes:
        n_near: how many; joints: the 0-based joints whose axis is nearly aligned (may be empty);
        relative: their |R_ii| / |R_00|.
    """

    def __init__(self, message: str, *, n_near: int, joints: tuple[int, ...], relative: tuple[float, ...]) -> None:
        super().__init__(message)
        self.n_near = n_near
        self.joints = joints
        self.relative = relative


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
        diagonal: |R_ii| / |R_00| of the pivoted QR of the torque-scaled regressor (decreasing), the
            evidence for the rank.
        note: why near-dependent combinations were counted as dependent ("" if there were none).
    """

    n_joints: int
    independent: np.ndarray
    dependent: np.ndarray
    coefficients: np.ndarray
    standard_names: tuple[str, ...]
    rank_tolerance: float
    diagonal: np.ndarray
    note: str = ""

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
        if self.note:
            lines.append(self.note)
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
            "note": self.note,
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
            note = str(d.get("note", ""))
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed base-parameter description: {e}") from e
        if sorted(np.concatenate([ind, dep]).tolist()) != list(range(10 * n)):
            raise IdentificationError(
                f"malformed base-parameter description: independent + dependent indices must cover 0..{10 * n - 1}"
            )
        return cls(n, ind, dep, K, names, tol, diag, note)


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
        robot: the arm (its kinematics and gravity direction; its masses set the parameter sizes).
        n_samples: random (q, dq, ddq) samples stacked into W ((n_samples n) x 10 n); a few times
            10 n / n rows are enough, more only cost time.
        seed: seed of the sampler.
        rank_tolerance: combinations with |R_ii| <= rank_tolerance |R_00| of the torque-scaled QR are
            dependent (see the module docstring and :data:`DEFAULT_RANK_TOLERANCE`).

    Raises:
        IdentificationError: the regressor is zero (no parameter moves any joint).

    Warns:
        NearlyDependentWarning: some combinations lie between round-off and ``rank_tolerance``: nearly
            aligned axes; they are counted as dependent, and the warning (and :attr:`BaseParameters.note`)
            names the joint whose axis is nearly aligned.
    """
    rng = np.random.default_rng(seed)
    q, dq, ddq = random_samples(robot, n_samples, rng)
    W = BatchRegressor(robot).compute_regressor(q, dq, ddq).reshape(-1, 10 * robot.n)
    # 1. the rank: pivoted QR of the columns as torques at typical parameter sizes (W diag(size)); what a
    # torque measurement cannot resolve is dependent
    size = parameter_sizes(robot)
    norms = np.linalg.norm(W * size, axis=0)
    if not np.any(norms > 0):
        raise IdentificationError(f"the regressor of {robot.name!r} is zero: no parameter moves any joint")
    _, R, _ = scipy.linalg.qr(W * size, mode="economic", pivoting=True)
    rel = np.abs(np.diag(R)) / abs(R[0, 0])
    nb = int(np.sum(rel > rank_tolerance))
    near = rel[nb:][rel[nb:] > ROUND_OFF_TOLERANCE]
    # 2. the representatives: pivoted QR of the resolvable columns scaled to unit norm (a column's share,
    # whatever its units); columns whose whole torque is below the tolerance never represent a combination
    zero = norms <= ROUND_OFF_TOLERANCE * norms.max()  # no effect on any joint torque
    strong = np.flatnonzero(norms > rank_tolerance * norms.max())
    unit = np.linalg.norm(W, axis=0)  # (the pivoting of equal-norm columns breaks ties by round-off: keep its order)
    _, _, perm = scipy.linalg.qr(W[:, strong] / unit[strong], mode="economic", pivoting=True)
    ind = strong[perm[:nb]]
    dep = np.setdiff1d(np.flatnonzero(~zero), ind)
    # 3. beta_b = pi_ind + K pi_dep: each dependent column in terms of the representatives (least squares,
    # in unit-norm coordinates; exact for dependent columns, the resolvable part for nearly dependent ones)
    c_ind, c_dep = unit[ind], unit[dep]
    K_n = np.linalg.lstsq(W[:, ind] / c_ind, W[:, dep] / c_dep, rcond=None)[0]
    K = np.hstack([K_n * c_dep[None, :] / c_ind[:, None], np.zeros((nb, int(zero.sum())))])
    K[np.abs(K) < 1e-12] = 0.0
    dep = np.concatenate([dep, np.flatnonzero(zero)])
    names = tuple(robot.inertial_parameter_names())
    note = ""
    if near.size:
        joints, why = nearly_aligned_axes(robot)
        note = (
            f"{near.size} combination(s) nearly dependent (|R_ii| / |R_00| = "
            f"{', '.join(f'{x:.2g}' for x in near)}, between round-off {ROUND_OFF_TOLERANCE:.0e} and the tolerance "
            f"{rank_tolerance:.0e}: torques below what a measurement resolves) counted as dependent: {why}"
        )
        warnings.warn(
            NearlyDependentWarning(
                f"{robot.name}: {note}; {nb} base parameters",
                n_near=int(near.size),
                joints=joints,
                relative=tuple(float(x) for x in near),
            ),
            stacklevel=2,
        )
    return BaseParameters(robot.n, ind, dep, K, names, float(rank_tolerance), rel, note)


def parameter_sizes(robot: RobotModel) -> np.ndarray:
    """Typical size of each of the 10 n inertial parameters: m, m l (first moments), m l^2 (inertias).

    m is the link's mass in the robot file (the mean of the positive ones for a massless link, 1 kg if
    all are), l the mean distance between consecutive joint origins (at least 0.05 m).
    """
    pin_model = robot.pin_model
    lengths = [float(np.linalg.norm(pin_model.jointPlacements[j].translation)) for j in range(1, pin_model.njoints)]
    length = max(float(np.mean(lengths)) if lengths else 0.0, _MIN_LENGTH_SCALE)
    mass = robot.inertial_parameters()[0::10]
    fallback = float(mass[mass > 0].mean()) if np.any(mass > 0) else 1.0
    mass = np.where(mass > 0, mass, fallback)
    per_link = np.array([1.0, length, length, length] + [length**2] * 6)
    return (mass[:, None] * per_link[None, :]).reshape(-1)


def nearly_aligned_axes(robot: RobotModel) -> tuple[tuple[int, ...], str]:
    """Joints whose axis is within :data:`_NEAR_ALIGNMENT` of parallel to gravity (joint 1) or to the
    previous joint's axis, but not within round-off of it: (0-based joints, a sentence naming them)."""
    q = np.zeros(robot.n)
    lo, hi = robot.lower_limit, robot.upper_limit
    q = np.where(np.isfinite(lo) & np.isfinite(hi) & ((lo > 0) | (hi < 0)), 0.5 * (lo + hi), q)
    axes = robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)[3:6].T  # (n, 3)
    g = robot.gravity
    found: list[tuple[int, str]] = []
    for j in range(robot.n):
        a = axes[j]
        if np.linalg.norm(a) < 0.5:  # a prismatic joint: no axis of rotation
            continue
        ref = [("gravity", g)] if j == 0 else [(f"joint {j} ({robot.joint_names[j - 1]})", axes[j - 1])]
        for what, b in ref:
            if np.linalg.norm(b) < 1e-12:
                continue
            cos = abs(float(a @ b)) / (np.linalg.norm(a) * np.linalg.norm(b))
            angle = float(np.arccos(np.clip(cos, -1.0, 1.0)))
            if 1e-12 < angle < _NEAR_ALIGNMENT:
                name = f"joint {j + 1} ({robot.joint_names[j]})"
                found.append((j, f"{name} axis is {angle:.2g} rad from parallel to {what}"))
    if not found:
        return (), "no nearly aligned axis found between consecutive joints or joint 1 and gravity"
    return tuple(j for j, _ in found), "; ".join(w for _, w in found) + " (a rounded angle in the robot file?)"


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
