"""HandPush: a hand pushes the end effector and holds it displaced (Fig. 11, "pushed manually and held")."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.sim.end_effector_force import EndEffectorForce
from reflexarm.sim.scene import Scene

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["HandPush"]


class HandPush(Scene):
    """A hand pushes the end effector and holds it displaced (Fig. 11: "pushed manually and held").

    The hand is a spring-damper along the push direction whose rest point moves ``depth`` into the
    end effector with a smooth (minimum-jerk) profile over ``t_ramp``, is held, and is withdrawn at
    ``t_release``. It can only push: the force is ``max(0, k (x_hand - x) + d (v_hand - v))`` along the
    direction, applied at the end-effector point. A human hand holding an object is far from rigid; its
    stiffness decides how much the arm's stiffening shows up as force and how much as position, as in
    Fig. 11 (both change).

    Args:
        depth: travel of the hand's rest point [m].
        stiffness: the hand's stiffness [N/m] (an assumption; Fig. 11 gives none, see
            :func:`reflexarm.experiments.compliance_loss.compliance_loss_sweep`).
        damping: the hand's damping [Ns/m].
        t_start, t_ramp, t_release: start, ramp duration and release time [s].
        direction: world unit vector of the push; None: normal to the end effector, as in
            :class:`reflexarm.sim.EndEffectorForce` (from the end-effector point towards the wrist sensor).
    """

    def __init__(
        self,
        depth: float = 0.10,
        stiffness: float = 2000.0,
        damping: float = 60.0,
        t_start: float = 0.5,
        t_ramp: float = 1.0,
        t_release: float = 4.0,
        direction: Sequence[float] | None = None,
    ) -> None:
        for name, v in (("depth", depth), ("stiffness", stiffness), ("t_ramp", t_ramp)):
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be positive; got {v!r}")
        if not (damping >= 0 and 0 <= t_start and t_start + t_ramp <= t_release):
            raise ConfigError("need damping >= 0 and 0 <= t_start, t_start + t_ramp <= t_release")
        self.depth, self.stiffness, self.damping = float(depth), float(stiffness), float(damping)
        self.t_start, self.t_ramp, self.t_release = float(t_start), float(t_ramp), float(t_release)
        self.direction = None if direction is None else np.asarray(direction, dtype=float) / np.linalg.norm(direction)
        self._reset_run()

    def _reset_run(self) -> None:
        self._u: np.ndarray | None = None
        self._p0 = np.zeros(3)
        self._handle: int | None = None
        self._force = np.zeros(3)
        self._target = np.zeros(3)
        self._last_x: float | None = None

    def reset(self, plant: Plant) -> None:
        self._reset_run()

    def _rest(self, t: float) -> tuple[float, float]:
        """Rest point travel [m] and its speed [m/s] at t."""
        if t < self.t_start or t >= self.t_release:
            return 0.0, 0.0
        s = min((t - self.t_start) / self.t_ramp, 1.0)
        pos = self.depth * (10 * s**3 - 15 * s**4 + 6 * s**5)
        vel = self.depth * (30 * s**2 - 60 * s**3 + 30 * s**4) / self.t_ramp if s < 1.0 else 0.0
        return pos, vel

    def update(self, plant: Plant) -> None:
        t = plant.time + 1e-9
        if self._handle is not None:
            plant.clear_external_force(self._handle)
            self._handle = None
        if t < self.t_start or t >= self.t_release:
            self._force = np.zeros(3)
            self._last_x = None
            return
        p = plant.ee_position()
        if self._u is None:
            if self.direction is None:
                self._u = EndEffectorForce(1.0).world_force(plant)
            else:
                self._u = self.direction.copy()
            self._p0 = p.copy()
        u = self._u
        dp = p - self._p0  # displacement of the end effector along the push (scalar sums: no BLAS, whose
        x = float(u[0] * dp[0] + u[1] * dp[1] + u[2] * dp[2])  # kernels fuse differently per CPU)
        v = 0.0 if self._last_x is None else (x - self._last_x) / plant.control_period
        self._last_x = x
        rest, rest_v = self._rest(t)
        self._target = self._p0 + u * rest
        f = max(0.0, self.stiffness * (rest - x) + self.damping * (rest_v - v))
        self._force = f * u
        if f > 0.0:
            self._handle = plant.apply_external_force(self._force)

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        return {"hand_force": self._force.copy(), "hand_target": self._target.copy()}

    def describe(self) -> dict[str, object]:
        return {
            "type": "HandPush",
            "depth": self.depth,
            "stiffness": self.stiffness,
            "damping": self.damping,
            "t_start": self.t_start,
            "t_ramp": self.t_ramp,
            "t_release": self.t_release,
        }
