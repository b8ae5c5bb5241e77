"""LinkForce: a force step on an arm link, a contact on the structure the wrist sensor does not see (Fig. 3)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.sim.scene import Scene

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["LinkForce"]


class LinkForce(Scene):
    """A force step on an arm link (a contact on the structure, not seen by the wrist sensor).

    Args:
        body: the link (MuJoCo body name).
        magnitude: force [N].
        t_on, t_off: step on and off [s].
        direction: world unit vector; None: horizontal and perpendicular to the radius from the first
            joint's (vertical) axis, i.e. the direction that turns the arm about that axis (pushing the
            elbow sideways, as the stick of Fig. 9), resolved at ``t_on``.
    """

    def __init__(
        self,
        body: str = "l_larm",
        magnitude: float = 50.0,
        t_on: float = 0.5,
        t_off: float = 3.5,
        direction: Sequence[float] | None = None,
    ) -> None:
        self.body = body
        self.magnitude = float(magnitude)
        self.t_on, self.t_off = float(t_on), float(t_off)
        self.direction = None if direction is None else np.asarray(direction, dtype=float) / np.linalg.norm(direction)
        self._handle: int | None = None
        self._force = np.zeros(3)
        self.point = np.zeros(3)

    def reset(self, plant: Plant) -> None:
        self._handle = None
        self._force = np.zeros(3)

    def world_force(self, plant: Plant) -> tuple[np.ndarray, np.ndarray]:
        """(force [N], point [m]) in the world if the force were switched on now: at the body origin."""
        m, d = plant.model, plant.data
        bid = m.body(self.body).id
        p = np.array(d.xpos[bid])
        if self.direction is not None:
            return self.magnitude * self.direction, p
        first = plant.model.joint(plant.joint_names[0]).id  # the arm's first joint
        r = p - np.array(d.xanchor[first])
        r[2] = 0.0
        u = np.cross(np.array(d.xaxis[first]), r)
        nrm = np.linalg.norm(u)
        if nrm < 1e-6:
            raise ConfigError(f"LinkForce: cannot derive a direction at body {self.body!r}; give direction=")
        return self.magnitude * u / nrm, p

    def update(self, plant: Plant) -> None:
        t = plant.time + 1e-9
        if self._handle is None and self.t_on <= t < self.t_off:
            self._force, self.point = self.world_force(plant)
            self._handle = plant.apply_external_force(self._force, self.point, body=self.body)
        elif self._handle is not None and t >= self.t_off:
            plant.clear_external_force(self._handle)
            self._handle = None
            self._force = np.zeros(3)

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        return {"link_force": self._force.copy()}

    def describe(self) -> dict[str, object]:
        return {
            "type": "LinkForce",
            "body": self.body,
            "magnitude": self.magnitude,
            "t_on": self.t_on,
            "t_off": self.t_off,
        }
