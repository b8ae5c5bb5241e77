"""Scene: what surrounds the arm in the simulated world (objects, pushes, applied forces).

A scene adds its bodies to the plant's MjSpec before compilation (:meth:`Scene.build`), may move
kinematic objects or apply forces once per control tick (:meth:`Scene.update`) and may report signals
for the recorded trace (:meth:`Scene.observe`). Everything a scene adds keeps physical contacts with
the arm: the plant never filters them.

Collision convention (see ``CONTACT_ARM``/``CONTACT_WORLD``): the arm's geoms collide with a scene geom
whose ``contype`` has bit 1; static scenery (floor, table) and hard object cores use bit 4 in both masks.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim._builder import CONTACT_ARM, CONTACT_WORLD

__all__ = ["CONTACT_ARM", "CONTACT_WORLD", "Scene", "add_floor"]


class Scene:
    """Base class of the scenes. Subclasses override what they need; every hook defaults to nothing.

    The hooks receive the :class:`~reflexarm.sim.plant.Plant` that runs them (typed ``Any`` here because the
    plant imports this module; subclasses annotate it as ``Plant``).

    A scene object may hold per-run state (e.g. a stick's approach direction, fixed at its start): use
    one scene object per plant at a time. Body names must be unique in the plant (pass ``name=``).
    """

    def build(self, spec: mujoco.MjSpec, robot: RobotModel) -> None:
        """Add bodies, geoms, joints to the plant's spec (called once, before compiling)."""

    def reset(self, plant: Any) -> None:
        """Called by :meth:`Plant.reset` after the state was reset (objects back at their initial poses)."""

    def update(self, plant: Any) -> None:
        """Called once per control tick, before the physics substeps (``plant.time`` is the tick's time)."""

    def observe(self, plant: Any) -> dict[str, np.ndarray]:
        """Scene signals recorded by :func:`run_closed_loop` into ``Trace.extras`` (fixed shapes per key)."""
        return {}

    def describe(self) -> dict[str, object]:
        """JSON-serialisable description for ``Trace.meta``."""
        return {"type": type(self).__name__}


def add_floor(spec: mujoco.MjSpec, name: str = "floor") -> None:
    """A ground plane at z = 0 that touches scene objects but not the arm (idempotent per name)."""
    if spec.geom(name) is not None:
        return
    spec.worldbody.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 0.05],
        contype=CONTACT_WORLD,
        conaffinity=CONTACT_WORLD,
        solref=[0.004, 1.0],
        rgba=[0.8, 0.8, 0.8, 1.0],
    )


def quat_from_x_axis(direction: np.ndarray) -> np.ndarray:
    """A unit quaternion (w, x, y, z) whose rotation maps the x axis onto ``direction`` (unit)."""
    x = np.array([1.0, 0.0, 0.0])
    d = np.asarray(direction, dtype=float)
    c = float(np.dot(x, d))
    if c < -1.0 + 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])  # 180 deg about z
    axis = np.cross(x, d)
    q = np.array([1.0 + c, *axis])
    return q / np.linalg.norm(q)
