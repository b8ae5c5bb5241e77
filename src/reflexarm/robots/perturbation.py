"""Model errors as a first-class input: seeded random scale factors on the controller's model.

Sec. III-C-2 of the paper: "The model errors were generated with uniformly distributed pseudo random
numbers between +-10 % as a scaling factor to all masses, inertias, center of mass coordinates and
friction coefficients." :class:`ModelPerturbation` draws those factors, :meth:`ModelPerturbation.apply`
builds the perturbed :class:`RobotModel` (the controller's model; the plant keeps the true one).

What is changed, per moving link j (Pinocchio merges fixed child bodies, e.g. a tool, into the link of
their joint, so "link" means the rigid body carried by joint j):

* the mass m_j, by one factor;
* each centre-of-mass coordinate c_x, c_y, c_z (in the joint frame), by one factor each, applied on a
  scale that means something for that coordinate: ``c' = c + (f - 1) * s`` with ``s = c`` where
  ``|c| >= rho_j`` (the paper's relative factor, ``c' = f c``) and ``s = rho_j`` where ``|c| < rho_j``.
  ``rho_j = sqrt(trace(I_c) / (2 m_j))`` is the link's radius of gyration about its COM, the RMS
  distance of its mass from the COM (its mass-weighted size). A relative factor on a zero coordinate
  is meaningless (it cannot move it; ten of the 21 Atlas COM coordinates are exactly 0 and six more
  are below 2 mm), so there the error is a fraction of the body's size instead: a level of 10 % moves
  such a coordinate by up to 10 % of rho_j (Atlas: rho_j = 3.4-7.5 cm, i.e. up to 3.4-7.5 mm at 10 %).
  The rotational inertia about the COM is left as it is, so the inertia about the joint changes by the
  parallel-axis term and stays physically valid whatever the COM does;
* the rotational inertia about the centre of mass: its three *principal moments* are scaled, one factor
  each, and the tensor is re-assembled with the unchanged principal axes,
  ``I_c' = R diag(f_1 I_1, f_2 I_2, f_3 I_3) R^T``. Scaling the six tensor entries independently can
  produce a matrix that is not positive definite or violates the triangle inequality of a physical body;
  scaling principal moments keeps it positive definite. The triangle inequality
  ``I_a <= I_b + I_c`` (which every real mass distribution satisfies) can still be violated for a flat
  body at large levels; the largest moment is then clipped to the sum of the other two (the flat-plate
  limit); :meth:`ModelPerturbation.clipped_links` names the links where that happened;
* each joint's Coulomb coefficient mu_C and viscous coefficient d_v, by one factor each.

The factors are ``1 + level * u`` with ``u ~ U(-1, 1)`` drawn from ``numpy.random.default_rng(seed)``
in a fixed order. The same seed therefore gives the same error *pattern* at every level (common random
numbers): a sweep over levels changes only the size of the errors, not their direction, which makes the
curves of Fig. 13 smooth in the level and keeps the trials of the two controller settings identical
("the model errors were the same in both plots").

What a level achieves in the dynamics is measured by :func:`measure_model_error` (relative error of
g(q) and M(q) over random joint states). The errors of independent factors partly cancel in the sums
that make g and M, so the achieved relative error is a fraction of the level (about 0.2 p for the
Atlas arm, median over states and seeds), growing linearly with it; see the module's tests for the
band and its derivation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "ModelErrorSize",
    "ModelPerturbation",
    "achieved_model_error",
    "com_error_scale",
    "measure_model_error",
    "perturb_model",
    "radius_of_gyration",
    "random_states",
]


def _check_level(level: object) -> float:
    try:
        p = float(level)  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise ConfigError(f"model error level must be a number in [0, 1); got {level!r}") from e
    if not math.isfinite(p) or p < 0.0:
        raise ConfigError(f"model error level must be non-negative (a fraction, 0.1 = +-10 %); got {level!r}")
    if p >= 1.0:
        raise ConfigError(
            f"model error level must be < 1 (a factor 1 - level <= 0 would make masses or inertias "
            f"non-positive); got {level!r}"
        )
    return p


def _check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise ConfigError(f"seed must be a non-negative integer; got {seed!r}")
    return int(seed)


def radius_of_gyration(mass: float, inertia_c: np.ndarray) -> float:
    """rho = sqrt(trace(I_c) / (2 m)) [m]: the RMS distance of a body's mass from its COM.

    ``trace(I_c) = 2 * sum(m_i r_i^2)`` for point masses m_i at distances r_i from the COM, hence the 2.
    A massless body (a frame) has rho = 0.
    """
    if mass <= 0.0:
        return 0.0
    return math.sqrt(max(float(np.trace(inertia_c)), 0.0) / (2.0 * mass))


def com_error_scale(com: np.ndarray, mass: float, inertia_c: np.ndarray) -> np.ndarray:
    """Scale s per COM coordinate on which the factor acts: ``c`` where ``|c| >= rho``, else ``rho`` [m]."""
    rho = radius_of_gyration(mass, inertia_c)
    return np.where(np.abs(com) >= rho, com, rho)


def _perturbed_com(com: np.ndarray, inertia_c: np.ndarray, mass: float, factors: np.ndarray) -> np.ndarray:
    return com + (factors - 1.0) * com_error_scale(com, mass, inertia_c)


@dataclass(frozen=True)
class ModelPerturbation:
    """Scale factors of one draw of model errors for an ``n``-joint arm.

    Attributes:
        level: p, the factors lie in [1 - p, 1 + p] [-].
        seed: seed of the draw.
        mass: factor per link (n,).
        com: factor per link and centre-of-mass coordinate (n, 3), applied on the coordinate's scale
            ``max(|c|, rho_j)`` (see the module docstring).
        inertia: factor per link and principal moment of inertia about the COM, ascending moments (n, 3).
        coulomb: factor per joint on mu_C (n,).
        viscous: factor per joint on d_v (n,).
    """

    level: float
    seed: int
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray

    @classmethod
    def draw(cls, n: int, level: float, seed: int = 0) -> ModelPerturbation:
        """Draw the factors ``1 + level * U(-1, 1)`` for ``n`` joints (see the module docstring)."""
        p = _check_level(level)
        s = _check_seed(seed)
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n <= 0:
            raise ConfigError(f"number of joints must be a positive integer; got {n!r}")
        rng = np.random.default_rng(s)
        # fixed order: 7 unit draws per link (mass, 3 COM, 3 moments), then 2 per joint (mu_C, d_v)
        u_link = rng.uniform(-1.0, 1.0, size=(n, 7))
        u_fric = rng.uniform(-1.0, 1.0, size=(n, 2))
        return cls(
            level=p,
            seed=s,
            mass=1.0 + p * u_link[:, 0],
            com=1.0 + p * u_link[:, 1:4],
            inertia=1.0 + p * u_link[:, 4:7],
            coulomb=1.0 + p * u_fric[:, 0],
            viscous=1.0 + p * u_fric[:, 1],
        )

    @classmethod
    def identity(cls, n: int) -> ModelPerturbation:
        """No model error (every factor 1)."""
        return cls.draw(n, 0.0, 0)

    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.mass.size)

    def _check_robot(self, robot: RobotModel) -> None:
        if robot.n != self.n:
            raise ConfigError(f"perturbation drawn for {self.n} joints cannot be applied to a {robot.n}-joint robot")

    def _scaled_inertial_parameters(self, robot: RobotModel) -> tuple[np.ndarray, tuple[int, ...]]:
        """(10 n parameters of the perturbed links, links whose moments were clipped)."""
        model = robot.pin_model
        params = []
        clipped = []
        for j in range(1, model.njoints):
            k = j - 1
            inertia = model.inertias[j]
            mass = float(inertia.mass) * self.mass[k]
            inertia_c0 = np.asarray(inertia.inertia, dtype=float)
            com = _perturbed_com(np.asarray(inertia.lever, dtype=float), inertia_c0, float(inertia.mass), self.com[k])
            moments, axes = np.linalg.eigh(inertia_c0)
            moments = np.maximum(moments, 0.0) * self.inertia[k]
            order = np.argsort(moments)
            a, b, c = moments[order]
            if c > a + b:  # triangle inequality of a real body: clip to the flat-plate limit
                moments[order[2]] = a + b
                clipped.append(k)
            inertia_c = (axes * moments) @ axes.T
            inertia_c = 0.5 * (inertia_c + inertia_c.T)
            params.append(np.asarray(pin.Inertia(mass, com, inertia_c).toDynamicParameters(), dtype=float))
        return np.concatenate(params), tuple(clipped)

    def apply(self, robot: RobotModel) -> RobotModel:
        """A new :class:`RobotModel`: ``robot`` with these factors applied (``robot`` is not modified).

        The result's inertial parameters are those of ``robot`` with masses and principal moments about
        the COM scaled, COM coordinates moved on their scale ``max(|c|, rho_j)``; its friction model is
        ``robot.friction`` scaled.
        """
        self._check_robot(robot)
        params, _ = self._scaled_inertial_parameters(robot)
        out = robot.with_inertial_parameters(params)
        return out.with_friction(robot.friction.scaled(self.coulomb, self.viscous))

    def clipped_links(self, robot: RobotModel) -> tuple[int, ...]:
        """Links (0-based joint index) whose scaled principal moments were clipped to the triangle inequality."""
        self._check_robot(robot)
        return self._scaled_inertial_parameters(robot)[1]

    def as_dict(self) -> dict[str, object]:
        """The factors as plain lists (JSON-serialisable)."""
        return {
            "level": self.level,
            "seed": self.seed,
            "mass": self.mass.tolist(),
            "com": self.com.tolist(),
            "inertia": self.inertia.tolist(),
            "coulomb": self.coulomb.tolist(),
            "viscous": self.viscous.tolist(),
        }


def perturb_model(robot: RobotModel, level: float, seed: int = 0) -> RobotModel:
    """The controller's model with uniform model errors within +-``level`` (see :class:`ModelPerturbation`).

    Args:
        robot: the true model (not modified).
        level: p >= 0 (0.1 = +-10 %, the paper's setting for Fig. 12), < 1.
        seed: seed of the draw; the same seed gives the same error pattern at every level.

    Raises:
        ConfigError: negative, non-finite or >= 1 level (naming the value), bad seed.
    """
    return ModelPerturbation.draw(robot.n, level, seed).apply(robot)


@dataclass(frozen=True)
class ModelErrorSize:
    """Achieved error of a perturbed model against the true one over random joint states.

    Relative errors per state: ``|g'(q) - g(q)|_2 / |g(q)|_2`` and ``|M'(q) - M(q)|_F / |M(q)|_F``.

    Attributes:
        gravity_median: median over the states of the relative error of g(q) [-].
        gravity_max: largest relative error of g(q) [-] (large where |g(q)| is small).
        mass_matrix_median: median over the states of the relative error of M(q) [-].
        mass_matrix_max: largest relative error of M(q) [-].
        n_states: number of states.
    """

    gravity_median: float
    gravity_max: float
    mass_matrix_median: float
    mass_matrix_max: float
    n_states: int

    def as_dict(self) -> dict[str, float | int]:
        """The numbers as a plain dict (JSON-serialisable)."""
        return {
            "gravity_median": self.gravity_median,
            "gravity_max": self.gravity_max,
            "mass_matrix_median": self.mass_matrix_median,
            "mass_matrix_max": self.mass_matrix_max,
            "n_states": self.n_states,
        }


def random_states(robot: RobotModel, n_states: int, seed: int = 0) -> np.ndarray:
    """(n_states, n) joint positions uniform within the limits (+-pi where a limit is infinite), seeded."""
    if isinstance(n_states, bool) or not isinstance(n_states, (int, np.integer)) or n_states <= 0:
        raise ConfigError(f"number of states must be a positive integer; got {n_states!r}")
    lo = np.where(np.isfinite(robot.lower_limit), robot.lower_limit, -math.pi)
    hi = np.where(np.isfinite(robot.upper_limit), robot.upper_limit, math.pi)
    return np.random.default_rng(_check_seed(seed)).uniform(lo, hi, size=(int(n_states), robot.n))


def measure_model_error(true: RobotModel, perturbed: RobotModel, n_states: int = 200, seed: int = 0) -> ModelErrorSize:
    """Relative error of ``perturbed``'s g(q) and M(q) against ``true``'s over seeded random states.

    States where ``|g(q)|`` is below 1e-9 of the largest one (a configuration with no gravity load) are
    left out of the gravity statistics (a relative error there is undefined).

    Raises:
        ConfigError: the two models have different numbers of joints, or a bad ``n_states``/``seed``.
    """
    if true.n != perturbed.n:
        raise ConfigError(f"models have {true.n} and {perturbed.n} joints; expected the same robot")
    qs = random_states(true, n_states, seed)
    g_num = np.empty(len(qs))
    g_den = np.empty(len(qs))
    m_rel = np.empty(len(qs))
    for i, q in enumerate(qs):
        g0 = true.compute_gravity(q)
        g_num[i] = np.linalg.norm(perturbed.compute_gravity(q) - g0)
        g_den[i] = np.linalg.norm(g0)
        m0 = true.compute_mass_matrix(q)
        m_rel[i] = np.linalg.norm(perturbed.compute_mass_matrix(q) - m0) / np.linalg.norm(m0)
    keep = g_den > 1e-9 * max(float(g_den.max()), 1e-300)
    g_rel = g_num[keep] / g_den[keep] if keep.any() else np.zeros(1)
    return ModelErrorSize(
        gravity_median=float(np.median(g_rel)),
        gravity_max=float(g_rel.max()),
        mass_matrix_median=float(np.median(m_rel)),
        mass_matrix_max=float(m_rel.max()),
        n_states=int(len(qs)),
    )


def achieved_model_error(
    robot: RobotModel, level: float, seed: int = 0, n_states: int = 200, state_seed: int = 0
) -> ModelErrorSize:
    """:func:`measure_model_error` of ``perturb_model(robot, level, seed)`` against ``robot``."""
    return measure_model_error(robot, perturb_model(robot, level, seed), n_states, state_seed)
