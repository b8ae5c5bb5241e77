"""EndEffectorForce: the force step on the end effector of the compensation simulation (Fig. 12)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.sim.scene import Scene

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["EndEffectorForce"]

_FRAMES = ("ee", "world")


class EndEffectorForce(Scene):
    """A force of ``magnitude`` newtons on the end-effector point from ``t_on`` to ``t_off`` (a step).

    At ``t_on`` the direction is resolved to the world frame and then held constant in the world
    (a weight hung on the hand, not a follower force); the point of application is the end-effector
    site and moves with the hand. The force goes through ``xfrc_applied``, so the wrist sensor and
    :meth:`Plant.true_external_torque` both see it.

    Args:
        magnitude: force [N] (paper: 50 N).
        direction: (3,) unit vector in ``frame``; None: "normal to the end effector", pushing against it
            along the axis from the wrist sensor to the end-effector point (for Atlas the hand's y axis);
            if both coincide, along -z of the end-effector frame.
        frame: ``"ee"`` (end-effector frame at ``t_on``) or ``"world"``.
        t_on: switch-on time [s] (paper: 0.5 s).
        t_off: switch-off time [s] (paper: 3.5 s); ``math.inf`` keeps it on.
        name: prefix of the recorded extra ``{name}_force`` (world force applied, (3,)).
    """

    def __init__(
        self,
        magnitude: float = 50.0,
        direction: npt.ArrayLike | None = None,
        t_on: float = 0.5,
        t_off: float = 3.5,
        *,
        frame: str = "ee",
        name: str = "ee_force",
    ) -> None:
        try:
            self.magnitude = float(magnitude)
            self.t_on = float(t_on)
            self.t_off = float(t_off)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"magnitude, t_on and t_off must be numbers: {e}") from e
        if not math.isfinite(self.magnitude) or self.magnitude < 0.0:
            raise ConfigError(f"magnitude must be a non-negative force [N]; got {magnitude!r}")
        if not math.isfinite(self.t_on) or self.t_on < 0.0 or not self.t_off > self.t_on:
            raise ConfigError(f"need 0 <= t_on < t_off [s]; got t_on={t_on!r}, t_off={t_off!r}")
        if frame not in _FRAMES:
            raise ConfigError(f"unknown frame {frame!r}; choose one of: {', '.join(_FRAMES)}")
        self.frame = frame
        if direction is None:
            self.direction: np.ndarray | None = None
        else:
            d = np.asarray(direction, dtype=float).reshape(-1)
            if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-12:
                raise ConfigError(f"direction must be a non-zero finite 3-vector; got {direction!r}")
            self.direction = d / np.linalg.norm(d)
        self.name = str(name)
        self._handle: int | None = None
        self._force = np.zeros(3)

    def world_force(self, plant: Plant) -> np.ndarray:
        """The force [N] in the world frame if it were switched on now."""
        d = plant.data
        R = d.site_xmat[plant._ee_site].reshape(3, 3)
        if self.direction is None:
            axis = d.site_xpos[plant._ee_site] - d.site_xpos[plant._sensor_site]
            norm = float(np.linalg.norm(axis))
            u = -axis / norm if norm > 1e-3 else -R[:, 2]
        else:
            u = R @ self.direction if self.frame == "ee" else self.direction
        return np.asarray(self.magnitude * u)

    def reset(self, plant: Plant) -> None:
        self._handle = None
        self._force = np.zeros(3)

    def update(self, plant: Plant) -> None:
        t = plant.time + 1e-9
        if self._handle is None and self.t_on <= t < self.t_off:
            self._force = self.world_force(plant)
            self._handle = plant.apply_external_force(self._force)
        elif self._handle is not None and t >= self.t_off:
            plant.clear_external_force(self._handle)
            self._handle = None
            self._force = np.zeros(3)

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        return {f"{self.name}_force": self._force.copy()}

    def describe(self) -> dict[str, object]:
        return {
            "type": "EndEffectorForce",
            "magnitude": self.magnitude,
            "direction": None if self.direction is None else self.direction.tolist(),
            "frame": self.frame,
            "t_on": self.t_on,
            "t_off": self.t_off,
        }
