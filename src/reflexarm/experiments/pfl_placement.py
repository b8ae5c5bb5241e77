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
from reflexarm.experiments.pfl_motion import SampledMotion, SpeedLimitError
from reflexarm.robots import RobotModel
from reflexarm.safety import ContactPoint, point_jacobian
from reflexarm.sim import JointTrajectory
from reflexarm.sim.human_contact import PATCH_HALF_SIZE

__all__ = [
    "MotionPlacement",
    "RegionPlacement",
    "contact_point_on",
    "place_region",
    "place_region_on_motion",
    "point_names",
    "swing_at_speed",
    "swing_motion",
]

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
        raise SpeedLimitError(
            f"{robot.name}: the end-effector swing (joint {j + 1}, {travel:.2f} rad) reaches at most {reach:.2f} m/s "
            f"within the joint's velocity limit {vlim:.2f} rad/s; asked for {speed:g} m/s",
            speed=speed,
            reachable_speed=reach,
            joint=j,
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


#: The run on a motion starts this long (file time [s]) before the contact, from the motion's state there.
LEAD_TIME = 0.5
#: Points along a link (fractions of the way from its joint to the next joint or the end effector) among which
#: the contact point is the fastest one.
LINK_FRACTIONS = (0.0, 0.25, 0.5, 0.75, 1.0)


def _link_frames(robot: RobotModel) -> list[str]:
    """The body frame of each joint's link (Pinocchio body frames; the MuJoCo bodies have the same names)."""
    import pinocchio as pin

    model = robot.pin_model
    out = []
    for j in range(1, robot.n + 1):
        names = [f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == j]
        if not names:
            raise ConfigError(f"{robot.name}: joint {j} carries no link body; no contact point on it")
        out.append(names[0])
    return out


def point_names(robot: RobotModel) -> list[str]:
    """The names ``--points`` accepts: ``ee`` and ``link1`` ... ``link<n>`` (the link each joint moves)."""
    return ["ee", *(f"link{j}" for j in range(1, robot.n + 1))]


def contact_point_on(robot: RobotModel, name: str, q: np.ndarray, dq: np.ndarray) -> tuple[ContactPoint, str | None]:
    """(the contact point, the MuJoCo body that carries it, None for the end-effector site) named ``name``
    (:func:`point_names`): for ``link<j>`` the point of :data:`LINK_FRACTIONS` along the link, from its joint to
    the next joint (the end effector for the last), whose largest speed over the samples q, dq is largest.

    Raises:
        ConfigError: an unknown name (the message lists the valid ones).
    """
    if name == "ee":
        return ContactPoint(robot.ee_frame), None
    if name not in point_names(robot):
        raise ConfigError(f"{robot.name}: unknown contact point {name!r}; choose from: {', '.join(point_names(robot))}")
    j = int(name[4:]) - 1
    links = _link_frames(robot)
    R, p0 = robot.compute_frame_pose(q[0], links[j])
    tip = links[j + 1] if j + 1 < robot.n else robot.ee_frame
    bone = R.T @ (robot.compute_frame_pose(q[0], tip)[1] - p0)
    best, best_speed = ContactPoint(links[j]), -1.0
    for f in LINK_FRACTIONS:
        local = tuple(float(x) for x in f * bone)
        pairs = zip(q[::5], dq[::5], strict=True)
        s = max(float(np.linalg.norm(point_jacobian(robot, qk, links[j], local)[0] @ v)) for qk, v in pairs)
        if s > best_speed + 1e-9:
            best, best_speed = ContactPoint(links[j], local), s  # type: ignore[arg-type]
    return best, links[j]


@dataclass(frozen=True)
class MotionPlacement:
    """The region on a motion's path: the point that hits it, its surface [m] and normal, the file times [s] of
    the run's start and of the contact, the point's speed there at the motion's scale [m/s], the posture [rad]."""

    point: ContactPoint
    arm_body: str | None
    surface: np.ndarray
    normal: np.ndarray
    start_time: float
    contact_time: float
    reference_speed: float
    q_contact: np.ndarray

    def describe(self) -> dict[str, Any]:
        return {
            "contact_point": self.point.label(),
            "arm_body": self.arm_body,
            "surface_m": self.surface.tolist(),
            "normal": self.normal.tolist(),
            "start_file_time_s": self.start_time,
            "contact_file_time_s": self.contact_time,
            "reference_speed_m_s": self.reference_speed,
            "q_contact_rad": self.q_contact.tolist(),
        }


def _first_crossing(robot: RobotModel, q: np.ndarray, frames: list[str], surface: np.ndarray, u: np.ndarray):
    """(frame, sample, depth [m]) of the first frame origin beyond the surface within the patch, else None."""
    for i in range(q.shape[0]):
        for name in frames:
            d = robot.compute_frame_pose(q[i], name)[1] - surface
            depth = float(d @ u)
            if depth > CROSSING_TOLERANCE and float(np.linalg.norm(d - depth * u)) < PATCH_HALF_SIZE:
                return name, i, depth
    return None


def place_region_on_motion(robot: RobotModel, motion: SampledMotion, name: str = "ee") -> MotionPlacement:
    """The region across the path of the point ``name`` (:func:`contact_point_on`) where it moves fastest along
    ``motion``, facing its direction of travel; the run starts :data:`LEAD_TIME` before (file time), later if the
    point itself is beyond the region's plane in between (the spring acts on the whole plane).

    Raises:
        ConfigError: the point does not move; another link's joint frame would cross the region's patch before
            the point reaches it (named, with the time).
    """
    tau, q, dq = motion.dense()
    point, body = contact_point_on(robot, name, q, dq)
    P, V = np.zeros((tau.size, 3)), np.zeros((tau.size, 3))
    for i in range(tau.size):
        J, P[i] = point_jacobian(robot, q[i], point.link, point.point)
        V[i] = J @ dq[i]
    speed = np.linalg.norm(V, axis=1)
    k = int(np.argmax(speed))
    if speed[k] < 1e-6:
        raise ConfigError(f"{robot.name}: point {name!r} does not move along {motion.name}; no region can be placed")
    u, surface = V[k] / speed[k], P[k].copy()
    i0 = int(np.searchsorted(tau, tau[k] - LEAD_TIME))
    beyond = np.flatnonzero((P[i0:k] - surface) @ u > 0.0)
    if beyond.size:
        i0 += int(beyond[-1]) + 1
    near = [f for f in (*_link_frames(robot), robot.ee_frame) if f != point.link]
    far = [f for f in near if np.linalg.norm(robot.compute_frame_pose(q[k], f)[1] - surface) > PATCH_HALF_SIZE]
    hit = _first_crossing(robot, q[i0:k], far, surface, u)
    if hit is not None:
        frame, i, depth = hit
        raise ConfigError(
            f"{robot.name}: frame {frame!r} crosses the region's surface {depth * 1e3:.0f} mm deep at file time "
            f"{tau[i0 + i]:.2f} s, before point {name!r} reaches it at {tau[k]:.2f} s: the region cannot be placed "
            "for this point on this motion (another link would hit it first)"
        )
    return MotionPlacement(point, body, surface, u, float(tau[i0]), float(tau[k]), float(speed[k]), q[k].copy())


def swing_motion(robot: RobotModel, plan: EeSwingPlan | None = None) -> SampledMotion:
    """The demo swing (:func:`~reflexarm.experiments.any_arm.ee_swing_plan`) at its own timing as a sampled motion
    (every 5 ms, with its velocities), for contacts at points other than the end effector."""
    plan = ee_swing_plan(robot) if plan is None else plan
    tr = plan.trajectory()
    t = np.arange(tr.t0, tr.t_end + 1e-9, 0.005)
    q, dq, _ = tr.sample_many(t)
    return SampledMotion(t, q, dq, name=f"{robot.name} demo swing")
