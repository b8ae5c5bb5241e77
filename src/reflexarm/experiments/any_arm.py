"""The experiments' setting on any serial arm: start posture, motions scaled to the arm's limits, and the
scenes placed from the arm's own kinematics (the cinderblock on the end effector's path, the stick at a link).

On the built-in Atlas arm (:func:`is_paper_arm`) the experiments keep the paper's setting exactly (the
constants of :mod:`reflexarm.experiments.collision`); on any other arm they derive it here, with the rules
stated in each function and nothing assumed about the number of joints, their names or their drives:

* start posture (:func:`start_posture`): the robot's home (built-in robots), else the file's keyframe
  named ``home`` (or its first keyframe, MJCF), else a working posture found by inverse kinematics
  (:func:`work_posture`: end effector in front, tool pointing down);
* the end-effector swing (:func:`ee_swing_plan`): the proximal joint that moves the end effector
  fastest horizontally swings it through ~:data:`SWING_PATH_M` at a peak speed of
  :data:`EE_PEAK_SPEED` (the paper's "moderate velocity"), inside the joint's range and below half
  its velocity limit;
* the cinderblock (:func:`~reflexarm.experiments.block_placement.place_cinderblock`): the end
  effector's path is computed by forward kinematics of that reference, and the block's padded face
  is put across the path where the rest of the path would still run ``depth`` into the block;
* the link push (:func:`~reflexarm.experiments.link_push.link_push_plan`): a mid-chain link swung
  across its radius, the stick coming against its motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.robots import RobotModel
from reflexarm.sim import JointTrajectory, Plant

__all__ = [
    "EE_PEAK_SPEED",
    "PAPER_ARM",
    "SWING_PATH_M",
    "EeSwingPlan",
    "ee_swing_plan",
    "is_paper_arm",
    "loaded_joints",
    "horizontal",
    "start_posture",
    "up_direction",
    "work_posture",
]

#: The built-in arm whose experiments keep the paper's constants.
PAPER_ARM = "atlas_v5_left_arm"
_PAPER_JOINTS = ("l_arm_shz", "l_arm_shx", "l_arm_ely", "l_arm_elx", "l_arm_wry", "l_arm_wrx", "l_arm_wry2")

#: Peak end-effector speed of the swing [m/s]: the demo on Atlas peaks at ~0.12 m/s, the paper's
#: "moderate velocity (100 mm/s)".
EE_PEAK_SPEED = 0.12
#: Length of the end effector's swing [m] (Atlas' demo: 1 rad of shz at ~0.5 m, ~0.5 m).
SWING_PATH_M = 0.5
#: Fraction of each joint's range kept free at both ends by every derived motion [-].
RANGE_MARGIN = 0.05
#: A derived motion uses at most this fraction of a joint's velocity limit [-].
VELOCITY_SHARE = 0.5


def is_paper_arm(robot: RobotModel) -> bool:
    """Whether ``robot`` is the built-in Atlas arm, on which the experiments keep the paper's setting."""
    return robot.name == PAPER_ARM and tuple(robot.joint_names) == _PAPER_JOINTS


def _finite_range(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) with the margin; unbounded joints get +-pi [rad]."""
    lo, hi = robot.lower_limit, robot.upper_limit
    bounded = np.isfinite(lo) & np.isfinite(hi) & (hi > lo) & (hi - lo < 1e6)
    lo = np.where(bounded, lo, -math.pi)
    hi = np.where(bounded, hi, math.pi)
    m = RANGE_MARGIN * (hi - lo)
    return lo + m, hi - m


def _keyframe(robot: RobotModel) -> np.ndarray | None:
    """The MJCF keyframe named ``home`` (else the first one) in the model's joint order, or None."""
    src = robot.source
    if src is None or src.suffix.lower() not in (".xml", ".mjcf"):
        return None
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(src).getroot()
    except (OSError, ET.ParseError):
        return None
    keys = root.findall("./keyframe/key")
    if not keys:
        return None
    key = next((k for k in keys if k.get("name") == "home"), keys[0])
    if key.get("qpos") is None:
        return None
    qpos = np.array([float(x) for x in key.get("qpos", "").split()])
    # qpos follows the file's joint order; the arm's joints are its 1-DoF joints in document order
    world = root.find("worldbody")
    if world is None:
        return None
    names = [j.get("name") for j in world.iter("joint") if j.get("type", "hinge") in ("hinge", "slide")]
    if len(names) != qpos.size:
        return None
    index = {name: i for i, name in enumerate(names)}
    if not all(name in index for name in robot.joint_names):
        return None
    return np.array([qpos[index[name]] for name in robot.joint_names])


#: Where :func:`start_posture` puts the end effector of an arm without a home: at this share of the arm's
#: reach from the first joint's axis, horizontally [-] ...
WORK_REACH_SHARE = 0.6
#: ... and this share of the reach above the shoulder (the second joint's origin) [-].
WORK_HEIGHT_SHARE = 0.3


def start_posture(robot: RobotModel) -> np.ndarray:
    """Where the experiments start on ``robot`` [rad]: its home if set (built-in robots), else the
    file's ``home`` keyframe (MJCF), else a working posture (:func:`work_posture`); within the
    range's margin."""
    lo, hi = _finite_range(robot)
    if np.any(robot.home != 0.0):
        return robot.home.copy()
    key = _keyframe(robot)
    q = work_posture(robot) if key is None else key
    return np.clip(q, lo, hi)


def work_posture(robot: RobotModel, iterations: int = 200) -> np.ndarray:
    """A posture with the end effector in front of the arm: from the middle of each joint's range,
    damped least squares (0.05 damping) moves it to :data:`WORK_REACH_SHARE` of the reach (the end
    effector's distance from the shoulder at the range middle) from the first joint's axis, at
    :data:`WORK_HEIGHT_SHARE` of the reach above the shoulder, in the end effector's horizontal
    direction at the start, with the tool axis pointing down (:func:`_tool_axis`); inside the ranges'
    margin."""
    lo, hi = _finite_range(robot)
    q = 0.5 * (lo + hi)
    up = up_direction(robot)
    names = robot.frame_names
    shoulder_frame = robot.joint_names[1] if robot.n > 1 else robot.joint_names[0]
    shoulder = robot.compute_frame_pose(q, shoulder_frame)[1] if shoulder_frame in names else np.zeros(3)
    base = robot.compute_frame_pose(q, robot.joint_names[0])[1] if robot.joint_names[0] in names else np.zeros(3)
    p = robot.compute_frame_pose(q)[1]
    reach = float(np.linalg.norm(p - shoulder))
    direction = horizontal(p - base, up)
    nd = float(np.linalg.norm(direction))
    direction = np.array([1.0, 0.0, 0.0]) if nd < 1e-6 else direction / nd
    target = horizontal(base, up) + direction * WORK_REACH_SHARE * reach
    target = target + up * float((shoulder @ up) + WORK_HEIGHT_SHARE * reach)
    for _ in range(iterations):
        R, p = robot.compute_frame_pose(q)
        axis = _tool_axis(robot, q, R, p)
        e = np.concatenate([target - p, np.cross(axis, -up)])  # position; tool axis down
        if float(np.linalg.norm(e)) < 1e-4:
            break
        J = robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)
        dq = J.T @ np.linalg.solve(J @ J.T + 0.05**2 * np.eye(6), e)
        q = np.clip(q + dq, lo, hi)
    return q


def _tool_axis(robot: RobotModel, q: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The tool axis (unit, world): from the wrist sensor to the end-effector point, else the end
    effector's z axis (the convention of :class:`~reflexarm.sim.EndEffectorForce`)."""
    axis = p - robot.compute_frame_pose(q, robot.sensor_frame)[1]
    n = float(np.linalg.norm(axis))
    return axis / n if n > 1e-3 else R[:, 2].copy()


def horizontal(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The part of ``v`` perpendicular to the unit vector ``up``."""
    return np.asarray(v - (v @ up) * up)


def up_direction(robot: RobotModel) -> np.ndarray:
    """The unit vector against the robot's gravity (z without gravity)."""
    g = robot.gravity
    n = float(np.linalg.norm(g))
    return np.array([0.0, 0.0, 1.0]) if n == 0.0 else -g / n


def swing(
    robot: RobotModel, q0: np.ndarray, joint: int, path: float, radius: float, speed: float, max_travel: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(start, goal, move time): joint ``joint`` travels about ``path / radius`` rad through q0, inside
    the range; the quintic's peak point speed 1.875 A r / T is ``speed``, its joint speed at most
    :data:`VELOCITY_SHARE` of the limit."""
    lo, hi = _finite_range(robot)
    travel = min(max_travel, path / max(radius, 1e-3), float(hi[joint] - lo[joint]))
    a = float(np.clip(q0[joint] + 0.5 * travel, lo[joint] + travel, hi[joint]))
    b = a - travel
    start, goal = q0.copy(), q0.copy()
    start[joint], goal[joint] = a, b
    t_move = 1.875 * travel * radius / speed
    vlim = robot.velocity_limit[joint]
    if np.isfinite(vlim) and vlim > 0:
        t_move = max(t_move, 1.875 * travel / (VELOCITY_SHARE * vlim))
    return start, goal, float(t_move)


def driving_joint(
    robot: RobotModel,
    q: np.ndarray,
    frame: str,
    joints: range,
    *,
    tangential: bool = False,
    point: np.ndarray | None = None,
) -> tuple[int, float]:
    """(joint, radius [m]): among ``joints`` the one whose rotation moves ``frame`` fastest horizontally,
    the horizontal speed weighted by its share of the speed (a swing that also lifts or lowers the frame
    ranks lower); ``tangential``: only the horizontal speed across the radius from the first joint
    counts (a swing about the base, so that an object met on the way lies beside the arm, not behind
    it); radius: that speed per rad. ``point``: a world point fixed to ``frame`` moved instead of the
    frame's origin."""
    p = robot.compute_frame_pose(q, frame)[1] if point is None else np.asarray(point, dtype=float)
    J = point_jacobian(robot, q, frame, p)
    up = up_direction(robot)
    lateral = np.eye(3)
    if tangential:
        radial = horizontal(p - _base_point(robot, q), up)
        nr = float(np.linalg.norm(radial))
        if nr > 1e-6:
            lateral = np.eye(3) - np.outer(radial, radial) / nr**2
    speeds = [float(np.linalg.norm(lateral @ horizontal(J[:, j], up))) for j in joints]
    scores = [v * v / max(float(np.linalg.norm(J[:, j])), 1e-9) for v, j in zip(speeds, joints, strict=True)]
    best = int(np.argmax(scores))
    if speeds[best] < 1e-3:
        raise ConfigError(
            f"no joint among {[j + 1 for j in joints]} moves frame {frame!r} horizontally at the start posture "
            f"{np.round(q, 3).tolist()} (1-based joints); give the robot a home posture"
        )
    return joints[best], speeds[best]


@dataclass(frozen=True)
class EeSwingPlan:
    """The end-effector collision's reference on one arm: hold, swing one joint, hold."""

    start: np.ndarray
    goal: np.ndarray
    joint: int  # 0-based
    move_time: float
    hold_before: float = 0.5
    hold_after: float = 2.0

    def trajectory(self) -> JointTrajectory:
        """Hold ``hold_before`` s, move in ``move_time``, hold ``hold_after`` s at the goal."""
        w = np.array([self.start, self.start, self.goal, self.goal])
        return JointTrajectory(w, np.array([self.hold_before, self.move_time, self.hold_after]))

    def describe(self) -> dict[str, Any]:
        return {
            "swing_joint": self.joint + 1,
            "start": self.start.tolist(),
            "goal": self.goal.tolist(),
            "move_time_s": self.move_time,
        }


def ee_swing_plan(robot: RobotModel, q0: np.ndarray | None = None) -> EeSwingPlan:
    """The swing of the end effector (module docstring): the joint among the first half of the chain
    that moves it fastest horizontally, ~:data:`SWING_PATH_M` at :data:`EE_PEAK_SPEED`, at most 1 rad."""
    q0 = start_posture(robot) if q0 is None else np.asarray(q0, dtype=float)
    joint, radius = driving_joint(robot, q0, robot.ee_frame, range(max(1, math.ceil(robot.n / 2))))
    start, goal, t_move = swing(robot, q0, joint, SWING_PATH_M, radius, EE_PEAK_SPEED, 1.0)
    return EeSwingPlan(start, goal, joint, t_move)


def geometry_plant(robot: RobotModel) -> Plant:
    """A scene-less plant of ``robot`` to read its collision geometry (the file's notes are not warned
    again: the experiment's own plant warns them)."""
    import warnings

    from reflexarm.robots import RobotFileWarning
    from reflexarm.sim import Plant

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        return Plant(robot)


def point_jacobian(robot: RobotModel, q: np.ndarray, frame: str, point: np.ndarray) -> np.ndarray:
    """3 x n Jacobian of the world ``point`` fixed to ``frame``: v_p = v + w x (p - origin)."""
    J6 = robot.compute_frame_jacobian(q, frame, world_aligned=True)
    r = np.asarray(point, dtype=float) - robot.compute_frame_pose(q, frame)[1]
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    return np.asarray(J6[:3] - skew @ J6[3:])


def _base_point(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """The first joint's origin (world) [m]."""
    name = robot.joint_names[0]
    return robot.compute_frame_pose(q, name)[1] if name in robot.frame_names else np.zeros(3)


def loaded_joints(robot: RobotModel, q: np.ndarray, count: int = 4) -> list[int]:
    """The ``count`` joints (0-based) with the largest load: |gravity torque| at ``q`` plus the friction
    torque at 0.3 rad/s (on Atlas: the four hydraulic joints)."""
    load = np.abs(robot.compute_gravity(q)) + np.abs(robot.friction.compute_torque(np.full(robot.n, 0.3)))
    return sorted(np.argsort(-load, kind="stable")[: min(count, robot.n)].tolist())


def loaded_waypoints(robot: RobotModel, q0: np.ndarray) -> np.ndarray:
    """Waypoints after ``q0`` that move the :func:`loaded_joints` together (pattern of Atlas' hydraulic
    free motion: each joint +-min(0.5 rad, 20 % of its range), clipped to the range)."""
    lo, hi = _finite_range(robot)
    joints = loaded_joints(robot, q0)
    amp = np.minimum(0.5, 0.2 * (hi - lo))
    pattern = np.array([[1.0, -1.0, 1.0, -1.0], [-1.0, 1.0, 1.0, -1.0], [0.5, 0.5, -1.0, 1.0]])
    out = []
    for row in pattern:
        q = q0.copy()
        for c, j in zip(row, joints, strict=False):
            q[j] += c * amp[j]
        out.append(np.clip(q, lo, hi))
    return np.array(out)
