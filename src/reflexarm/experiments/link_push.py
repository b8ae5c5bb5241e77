"""The link collision (Sec. III-B, Figs. 9-10) on any arm: which link the stick pushes, how the arm swings it
and where the stick appears (:class:`~reflexarm.sim.ElbowStick`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import driving_joint, geometry_plant, point_jacobian, start_posture, swing
from reflexarm.robots import RobotModel
from reflexarm.sim import JointTrajectory

__all__ = [
    "HELD_STICK_GAP_M",
    "LINK_PATH_M",
    "LINK_SPEED",
    "STICK_GAP_M",
    "LinkPushPlan",
    "default_link",
    "held_stick_tip",
    "link_body",
    "link_push_plan",
    "move_start",
]

#: Peak speed of the pushed link in the link collision [m/s] (the paper's elbow moved at ~50 mm/s).
LINK_SPEED = 0.05
#: Length of the link's swing [m] (Atlas' link collision: 0.8 rad of shz, ~0.3 m at the elbow).
LINK_PATH_M = 0.3


def _body_frame(robot: RobotModel, joint: int) -> str:
    m = robot.pin_model
    for f in m.frames:
        if f.parentJoint == joint + 1 and f.type == pin.FrameType.BODY:
            return str(f.name)
    raise ConfigError(f"joint {joint + 1} ({robot.joint_names[joint]}) has no link frame in {robot.name!r}")


def default_link(robot: RobotModel) -> int:
    """The mid-chain link the link collision pushes: that of joint ceil(n/2) (1-based; Atlas: 4, elx)."""
    return max(1, math.ceil(robot.n / 2))


def link_body(robot: RobotModel, link: int | str) -> tuple[int, str]:
    """(joint, body name): ``link`` is a 1-based joint number (its child link) or a link/body name.

    Raises:
        ConfigError: a number outside 1..n or an unknown name (naming the choices).
    """
    names = [_body_frame(robot, j) for j in range(robot.n)]
    if isinstance(link, str) and not link.strip().lstrip("-").isdigit():
        if link not in names:
            raise ConfigError(f"unknown link {link!r}; links are: {', '.join(names)} (or a joint number 1..{robot.n})")
        return names.index(link), link
    k = int(link)
    if not 1 <= k <= robot.n:
        raise ConfigError(f"link must be a joint number in 1..{robot.n} or a link name; got {link}")
    return k - 1, names[k - 1]


@dataclass(frozen=True)
class LinkPushPlan:
    """The link collision on one arm: the reference and where and when the stick pushes."""

    trajectory: JointTrajectory
    body: str
    joint: int  # 0-based swing joint
    link_joint: int  # 0-based joint whose link is pushed
    t_start: float
    info: dict[str, Any] = field(default_factory=dict)
    standoff: float = 0.10  # stick tip to the target point at t_start [m] (ElbowStick's standoff)


def link_push_plan(robot: RobotModel, link: int | str | None = None) -> LinkPushPlan:
    """Swing the link of ``link`` (default :func:`default_link`) at ~:data:`LINK_SPEED` about the base
    (the joint that moves it fastest across its radius, so the stick, coming against the motion, lies
    beside the arm); the stick appears 40 % into the move (Atlas: 5 s into the 1 + 10 s)."""
    link_joint, body = link_body(robot, default_link(robot) if link is None else link)
    q0 = start_posture(robot)
    # the link's middle: between its origin and the next link's (or the end effector)
    after = robot.compute_frame_pose(q0, link_body(robot, link_joint + 2)[1] if link_joint + 1 < robot.n else None)[1]
    middle = 0.5 * (robot.compute_frame_pose(q0, body)[1] + after)
    joint, radius = driving_joint(robot, q0, body, range(link_joint + 1), tangential=True, point=middle)
    start, goal, t_move = swing(robot, q0, joint, LINK_PATH_M, radius, LINK_SPEED, 0.8)
    w = np.array([start, start, goal, goal])
    traj = JointTrajectory(w, np.array([1.0, t_move, 2.0]))
    t_start = 1.0 + 0.4 * t_move
    standoff = STICK_GAP_M + _extent_along_motion(robot, traj.sample(t_start).q_d, body, joint, goal - start)
    info = {
        "link": link_joint + 1,
        "body": body,
        "swing_joint": joint + 1,
        "move_time_s": t_move,
        "stick_standoff_m": standoff,
    }
    return LinkPushPlan(traj, body, joint, link_joint, t_start, info, standoff)


#: Gap between the link's surface and the stick's tip when the stick appears [m] (on Atlas' forearm the
#: paper setting's 0.10 m standoff leaves ~5 cm).
STICK_GAP_M = 0.05


def _extent_along_motion(robot: RobotModel, q: np.ndarray, body: str, joint: int, delta: np.ndarray) -> float:
    """How far the collision geoms of ``body`` reach from the stick's target point (the centre of its
    first collision geom, :class:`~reflexarm.sim.ElbowStick`) in the direction it moves at ``q`` when
    ``joint`` moves by ``delta`` [m] (the geoms' own bounding boxes)."""
    import mujoco

    plant = geometry_plant(robot)
    m, d = plant.model, plant.data
    d.qpos[plant._qadr_arr] = q
    mujoco.mj_kinematics(m, d)
    bid = m.body(body).id
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == bid and (m.geom_contype[g] or m.geom_conaffinity[g])]
    if not geoms:
        return 0.0
    p = np.array(d.geom_xpos[geoms[0]])
    v = point_jacobian(robot, q, body, p)[:, joint] * float(np.sign(delta[joint]))
    nv = float(np.linalg.norm(v))
    if nv < 1e-9:
        return 0.0
    v /= nv
    reach = []
    for g in geoms:  # each geom's bounding box (in its own frame) projected on v
        R = np.array(d.geom_xmat[g]).reshape(3, 3)
        centre = np.array(d.geom_xpos[g]) + R @ m.geom_aabb[g, :3]
        reach.append(float((centre - p) @ v + np.abs(R.T @ v) @ m.geom_aabb[g, 3:]))
    return max(reach)


#: A held stick's tip sits this far ahead of the link's surface when it appears [m] (at least).
HELD_STICK_GAP_M = 0.02


def held_stick_tip(
    robot: RobotModel, body: str, traj: JointTrajectory, t_start: float, radius: float = 0.015
) -> tuple[np.ndarray, np.ndarray]:
    """(tip, direction) of a held stick on the link's path: of the link's surface points (its collision geometry,
    :func:`~reflexarm.robots.collision_geometry.link_collision_geometry`, 2 cm apart), the one moving fastest
    along its outward normal along the reference after ``t_start``, at the time it does, among the positions
    :data:`HELD_STICK_GAP_M` outside the link at ``t_start``; the stick's tip (``radius``) just touches that
    position, pointing against the point's motion. The link's surface runs into it whatever the curvature of its
    path (a stick placed on the tangent at ``t_start`` misses a link swung on a tight circle, e.g. the Panda's
    link 4 about joint 3).

    Raises:
        ConfigError: a link without collision geometry, or one that never moves clear of where it was.
    """
    from scipy.spatial import cKDTree

    from reflexarm.control.collision.identify import compute_link_kinematics
    from reflexarm.robots.collision_geometry import link_collision_geometry

    joint = link_body(robot, body)[0]
    surface = link_collision_geometry(robot, spacing=0.02)[joint]
    if not surface.has_geometry:
        raise ConfigError(f"the link {body!r} has no collision geometry: a held stick cannot touch it")
    ts = np.arange(t_start, traj.duration, 5e-3)
    pose = [compute_link_kinematics(robot, traj.sample(float(t)).q_d) for t in ts]
    pts = np.array([surface.points @ k.rotations[joint].T + k.origins[joint] for k in pose])  # (time, point, 3)
    normals = np.array([surface.normals @ k.rotations[joint].T for k in pose])
    vel = np.gradient(pts, ts, axis=0)
    lead = np.einsum("tmi,tmi->tm", vel, normals)  # speed along the outward normal
    # outside the link at t_start: away from the nearest surface point, on its outer side
    flat = pts.reshape(-1, 3)
    gap, near = cKDTree(pts[0]).query(flat)
    outer = np.einsum("ki,ki->k", flat - pts[0][near], normals[0][near]) > 0.0
    clear = ((gap >= HELD_STICK_GAP_M) & outer).reshape(lead.shape)
    if not clear.any() or np.where(clear, lead, 0.0).max() <= 0.0:
        raise ConfigError(f"the link {body!r} never moves clear of where it was after t = {t_start:g} s: no path to "
                          "hold a stick on")  # fmt: skip
    k, i = np.unravel_index(int(np.argmax(np.where(clear, lead, -np.inf))), lead.shape)
    direction = -vel[k, i] / np.linalg.norm(vel[k, i])
    return pts[k, i] - direction * radius, direction


def move_start(traj: JointTrajectory) -> float:
    """The first time [s] the reference leaves its start (1 ms steps)."""
    q0 = traj.sample(0.0).q_d
    for t in np.arange(0.0, traj.duration, 1e-3):
        if np.abs(traj.sample(float(t)).q_d - q0).max() > 1e-9:
            return float(t)
    raise ConfigError("the link collision's reference never moves")
