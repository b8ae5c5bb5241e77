"""The scenes of ``reflexarm ros sim`` with the motion that goes with each, as the demo and the link collision
build them (:mod:`reflexarm.experiments.collision`): the simulated robot takes the scene and the start posture,
the control node (``reference`` = the scene's name) the same trajectory, timed from the first stamp it hears."""

from __future__ import annotations

from typing import NamedTuple

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim.scene import Scene
from reflexarm.sim.trajectory import JointTrajectory

__all__ = ["Scenario", "scenario"]


class Scenario(NamedTuple):
    """A scene (None: nothing around the arm) and the joint motion that runs into it."""

    scene: Scene | None
    trajectory: JointTrajectory


def scenario(name: str, robot: RobotModel, *, with_scene: bool = True) -> Scenario:
    """The scenario ``name`` ("demo", "link", "free", "none") on ``robot``: the demo's cinderblock ("paper"
    variant) and swing, the link collision's pushed stick and motion, the demo's swing without obstacle (twice),
    or the start posture held. ``with_scene=False`` skips building the scene (the controller needs the motion only).
    """
    from reflexarm.experiments import collision as c
    from reflexarm.experiments.any_arm import ee_swing_plan, is_paper_arm, start_posture
    from reflexarm.sim import Cinderblock, ElbowStick

    paper = is_paper_arm(robot)
    if name == "demo":
        if paper:
            traj = c.ee_collision_trajectory()
            return Scenario(Cinderblock(**c.EE_BLOCK) if with_scene else None, traj)  # type: ignore[arg-type]
        from reflexarm.experiments.block_placement import place_cinderblock

        traj = ee_swing_plan(robot).trajectory()
        if not with_scene:
            return Scenario(None, traj)
        placement = place_cinderblock(robot, traj, depth=0.12)
        kwargs = {k: v for k, v in placement.items() if k not in ("contact_time_s", "depth", "ee_height_m")}
        return Scenario(Cinderblock(**kwargs, mass=20.0), traj)  # type: ignore[arg-type]
    if name == "link":
        if paper:
            scene = ElbowStick(body="l_larm", t_start=5.0) if with_scene else None
            return Scenario(scene, c.link_collision_trajectory())
        from reflexarm.experiments.link_push import link_push_plan

        plan = link_push_plan(robot)
        stick = ElbowStick(body=plan.body, t_start=plan.t_start, standoff=plan.standoff) if with_scene else None
        return Scenario(stick, plan.trajectory)
    if name == "free":
        return Scenario(None, c.free_motion_trajectory(2 * (c.EE_MOVE_TIME + 0.5) * 2, "demo", robot))
    if name == "none":
        q0 = c.EE_START if paper else start_posture(robot)
        return Scenario(None, JointTrajectory(q0[None, :].repeat(2, axis=0), [1.0]))
    raise ConfigError(f"unknown scene {name!r}; scenes are: demo, link, free, none")
