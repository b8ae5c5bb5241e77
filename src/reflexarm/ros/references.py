"""The control node's joint reference: the first posture held, a JointState topic, or a scene's trajectory."""

from __future__ import annotations

from typing import Any

import numpy as np

from reflexarm.robots.robot_model import RobotModel
from reflexarm.ros.config import MonitorConfig
from reflexarm.ros.inputs import JointStateReader
from reflexarm.signals import Reference

__all__ = ["ReferenceSource"]


class ReferenceSource:
    """``sample(t, q)`` -> :class:`Reference` for the tick at ``t`` [s since the first stamp] with the measured
    posture ``q``, as ``config.reference`` says (:data:`~reflexarm.ros.config.REFERENCES`). Until a reference
    message arrived (``topic``) the first measured posture is held."""

    def __init__(self, config: MonitorConfig, model: RobotModel) -> None:
        self.kind = config.reference
        self.trajectory = None
        if self.kind not in ("hold", "topic"):
            from reflexarm.ros.scenarios import scenario

            self.trajectory = scenario(self.kind, model, with_scene=False).trajectory
            self.trajectory.sample(0.0)  # compiled on first use (seconds): not in the first tick
        self._reader = JointStateReader(model.joint_names, config.reference_topic, ("position", "velocity"))
        self._zeros = np.zeros(model.n)
        self._hold: Reference | None = None
        self._latest: Reference | None = None
        self.fault = ""

    def reset(self) -> None:
        """Forget the held posture (the next tick's is held)."""
        self._hold = None

    def on_message(self, msg: Any) -> None:
        """A reference JointState (position and velocity for every joint, by name; effort is ignored)."""
        read = self._reader.read(msg)
        if isinstance(read, str):
            self.fault = read.replace("JointState", "reference JointState")
            return
        self.fault = ""
        self._latest = Reference(read[0], read[1], self._zeros)

    def sample(self, t: float, q: np.ndarray) -> Reference:
        """The reference of the tick at ``t`` [s]."""
        if self.trajectory is not None:
            return self.trajectory.sample(t)  # type: ignore[no-any-return]
        if self._latest is not None:
            return self._latest
        if self._hold is None:
            self._hold = Reference(q.copy(), self._zeros, self._zeros)
        return self._hold
