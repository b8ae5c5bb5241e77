"""Model errors as a first-class input: seeded random scale factors on the controller's model.

Sec. III-C-2 of the paper: "The model errors were generated with uniformly distributed pseudo random
numbers between +-10 % as a scaling factor to all masses, inertias, center of mass coordinates and
friction coefficients." :class:`ModelPerturbation` draws those factors, :meth:`ModelPerturbation.apply`
builds the perturbed :class:`RobotModel` (the controller's model; the plant keeps the true one).

What is scaled, per moving link j (Pinocchio merges fixed child bodies, e.g. a tool, into the link of
their joint, so "link" means the rigid body carried by joint j):

* the mass m_j, by one factor;
* each centre-of-mass coordinate c_x, c_y, c_z (in the joint frame), by one factor each (a zero
  coordinate stays zero: a scale factor cannot move it);
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

__all__ = ["ModelPerturbation", "perturb_model"]


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


@dataclass(frozen=True)
class ModelPerturbation:
    """Scale factors of one draw of model errors for an ``n``-joint arm.

    Attributes:
        level: p, the factors lie in [1 - p, 1 + p] [-].
        seed: seed of the draw.
        mass: factor per link (n,).
        com: factor per link and centre-of-mass coordinate (n, 3).
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
            com = np.asarray(inertia.lever, dtype=float) * self.com[k]
            moments, axes = np.linalg.eigh(np.asarray(inertia.inertia, dtype=float))
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

        The result's inertial parameters are those of ``robot`` with masses, COM coordinates and
        principal moments about the COM scaled; its friction model is ``robot.friction`` scaled.
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
