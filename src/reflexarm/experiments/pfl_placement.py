"""The human body region placed on the arm's path: the demo's end-effector swing (the same swing whose path
places the demo's cinderblock, :func:`~reflexarm.experiments.any_arm.ee_swing_plan`), run at a chosen peak
speed, and the region's surface put across the end effector's path where it moves fastest, facing its
direction of travel there."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import EeSwingPlan, ee_swing_plan
from reflexarm.robots import RobotModel
from reflexarm.sim import JointTrajectory
from reflexarm.sim.human_contact import PATCH_HALF_SIZE

__all__ = ["RegionPlacement", "place_region", "swing_at_speed"]

#: A frame of the arm this far beyond the region's surface [m], within its patch, before the end effector
#: reaches it, makes the placement fail: another part of the arm would hit the region first.
CROSSING_TOLERANCE = 0.005
#: Samples of the reference for the placement [-].
SAMPLES = 600


@dataclass(frozen=True)
class RegionPlacement:
    """Where the region stands: its surface point [m] and normal (the end effector's direction of travel),
    the reference's contact time [s] and speed there [m/s], and the posture then [rad]."""

    surface: np.ndarray
    normal: np.ndarray
    contact_time: float
    reference_speed: float
    q_contact: np.ndarray

    def describe(self) -> dict[str, Any]:
        return {
            "surface_m": self.surface.tolist(),
            "normal": self.normal.tolist(),
            "contact_time_s": self.contact_time,
            "reference_speed_m_s": self.reference_speed,
            "q_contact_rad": self.q_contact.tolist(),
        }


def _ee_path(robot: RobotModel, trajectory: JointTrajectory, samples: int) -> tuple[np.ndarray, ...]:
    t = np.linspace(trajectory.t0, trajectory.t_end, samples)
    q, dq, _ = trajectory.sample_many(t)
    P = np.array([robot.compute_frame_pose(qk)[1] for qk in q])
    V = np.array(
        [
            robot.compute_frame_jacobian(qk, robot.ee_frame, world_aligned=True)[:3] @ v
            for qk, v in zip(q, dq, strict=True)
        ]
    )
    return t, q, P, V


def swing_at_speed(robot: RobotModel, speed: float, plan: EeSwingPlan | None = None) -> tuple[JointTrajectory, float]:
    """(the demo swing of ``robot`` retimed so that its end effector's reference peaks at ``speed`` [m/s], the
    swing's move time [s]).

    Raises:
        ConfigError: a non-positive speed, or one the swing cannot reach within the swinging joint's
            velocity limit (the message names the largest reachable speed).
    """
    if not (math.isfinite(speed) and speed > 0.0):
        raise ConfigError(f"speed must be a positive speed [m/s]; got {speed!r}")
    plan = ee_swing_plan(robot) if plan is None else plan
    _, _, _, V = _ee_path(robot, plan.trajectory(), SAMPLES)
    v0 = float(np.max(np.linalg.norm(V, axis=1)))
    move = plan.move_time * v0 / speed
    j = plan.joint
    travel = abs(float(plan.goal[j] - plan.start[j]))
    vlim = float(robot.velocity_limit[j])
    if math.isfinite(vlim) and vlim > 0.0 and 1.875 * travel / move > vlim:
        reach = v0 * plan.move_time * vlim / (1.875 * travel)
        raise ConfigError(
            f"{robot.name}: the end-effector swing (joint {j + 1}, {travel:.2f} rad) reaches at most {reach:.2f} m/s "
            f"within the joint's velocity limit {vlim:.2f} rad/s; asked for {speed:g} m/s"
        )
    w = np.array([plan.start, plan.start, plan.goal, plan.goal])
    return JointTrajectory(w, np.array([plan.hold_before, move, plan.hold_after])), move


def _frames_to_check(robot: RobotModel) -> list[str]:
    """The joints' frames except the last two (the wrist, beside the end effector)."""
    return [j for j in robot.joint_names[: max(0, robot.n - 2)] if j in robot.frame_names]


def place_region(robot: RobotModel, trajectory: JointTrajectory, *, samples: int = SAMPLES) -> RegionPlacement:
    """The region across the end effector's path where its reference speed peaks (module docstring).

    Raises:
        ConfigError: the end effector does not move; a joint frame of the arm (not the wrist's) would cross
            the region's patch (:data:`~reflexarm.sim.human_contact.PATCH_HALF_SIZE`) before the end effector
            reaches it (the message names the frame and the time).
    """
    t, q, P, V = _ee_path(robot, trajectory, samples)
    speed = np.linalg.norm(V, axis=1)
    k = int(np.argmax(speed))
    if speed[k] < 1e-6:
        raise ConfigError(
            f"{robot.name}: the end effector does not move along this trajectory; no region can be placed"
        )
    u = V[k] / speed[k]
    surface = P[k]
    for name in _frames_to_check(robot):
        for i in range(k):
            d = robot.compute_frame_pose(q[i], name)[1] - surface
            depth = float(d @ u)
            lateral = float(np.linalg.norm(d - depth * u))
            if depth > CROSSING_TOLERANCE and lateral < PATCH_HALF_SIZE:
                raise ConfigError(
                    f"{robot.name}: frame {name!r} crosses the region's surface {depth * 1e3:.0f} mm deep at "
                    f"t = {t[i]:.2f} s, before the end effector reaches it at {t[k]:.2f} s: the region cannot be "
                    "placed on this path (the arm would hit it with another link first)"
                )
    return RegionPlacement(surface.copy(), u, float(t[k]), float(speed[k]), q[k].copy())
