"""The arm's effective mass at a contact point and the permissible speed of a transient contact with a body
region (ISO/TS 15066 Annex A.3, with the arm's posture-dependent mass beside the standard's simple one).

Transient contact as two masses and a spring (A.3): the energy 1/2 mu v^2 goes into the region's spring,
F^2 / (2k), so the peak force is F = v sqrt(mu k) and the permissible relative speed

    v_max = F_T / sqrt(mu k),      mu = (1/m_H + 1/m_R)^-1.

The standard's robot mass is m_R = M/2 + m_L (M the moving mass of the robot, m_L the payload); the arm's
effective mass at a point p of a link, in the unit direction u of the contact force, is

    m_R(q, u) = 1 / (u^T J_p(q) M(q)^-1 J_p(q)^T u)

(J_p the translational Jacobian of p): the mass a force along u at p accelerates, with every joint free
(no brake, no controller torque during the impact).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots import RobotModel
from reflexarm.safety.body_regions import BodyRegion, body_region

__all__ = [
    "ContactPoint",
    "contact_points",
    "effective_mass",
    "moving_mass",
    "peak_transient_force",
    "permissible_speed",
    "permissible_speed_for_mass",
    "point_jacobian",
    "reduced_mass",
    "standard_robot_mass",
]


@dataclass(frozen=True)
class ContactPoint:
    """A point fixed to a link of the arm: the Pinocchio frame ``link`` (a link, joint or any frame of the model)
    and the point's coordinates in that frame [m]."""

    link: str
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def label(self) -> str:
        p = ", ".join(f"{x:g}" for x in self.point)
        return self.link if not any(self.point) else f"{self.link}@({p})"


def _vector3(value: npt.ArrayLike, name: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a 3-vector; got {value!r}") from e
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be a finite 3-vector; got {np.asarray(value).tolist()!r}")
    return v


def _unit(direction: npt.ArrayLike) -> np.ndarray:
    u = _vector3(direction, "direction")
    n = float(np.linalg.norm(u))
    if n < 1e-12:
        raise ConfigError(f"direction must be a non-zero 3-vector; got {u.tolist()}")
    return u / n


def point_jacobian(
    robot: RobotModel, q: npt.ArrayLike, link: str, point: npt.ArrayLike = (0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """(J (3, n), p (3,)): the translational Jacobian (world axes) of the point ``point`` [m], given in the frame
    ``link``, and its world position [m] at ``q``.

    Raises:
        ModelError: an unknown frame (the message lists the model's frames).
        ConfigError: a point that is not a finite 3-vector.
    """
    local = _vector3(point, "point")
    R, origin = robot.compute_frame_pose(q, link)
    J6 = robot.compute_frame_jacobian(q, link, world_aligned=True)
    r = R @ local
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    return np.asarray(J6[:3] - skew @ J6[3:]), origin + r


def effective_mass(
    robot: RobotModel, q: npt.ArrayLike, link: str, point: npt.ArrayLike, direction: npt.ArrayLike
) -> float:
    """m_R(q, u) = 1 / (u^T J M^-1 J^T u) [kg] of the point ``point`` (coordinates in frame ``link`` [m]) in the
    world direction ``direction`` (normalised here).

    Returns ``inf`` where the arm cannot move the point along u at all (u^T J M^-1 J^T u = 0: a singular
    direction, e.g. along a stretched arm or at the base): a contact there meets the whole mounting.
    """
    u = _unit(direction)
    J, _ = point_jacobian(robot, q, link, point)
    M = robot.compute_mass_matrix(q)
    Ju = J.T @ u
    mobility = float(Ju @ np.linalg.solve(M, Ju))  # u^T J M^-1 J^T u [1/kg]
    scale = float(np.trace(M)) / M.shape[0]
    return math.inf if mobility * scale < 1e-12 else 1.0 / mobility


def moving_mass(robot: RobotModel) -> float:
    """M: the mass of the robot's moving parts [kg], the bodies carried by its joints (a cut arm's locked bodies
    on the base are not counted)."""
    model = robot.pin_model
    return float(sum(model.inertias[j].mass for j in range(1, model.njoints)))


def standard_robot_mass(robot: RobotModel, payload: float = 0.0) -> float:
    """The standard's m_R = M/2 + m_L [kg] (ISO/TS 15066 A.3): half the moving mass plus the payload ``payload``
    [kg]."""
    if not (math.isfinite(payload) and payload >= 0.0):
        raise ConfigError(f"payload must be a non-negative mass [kg]; got {payload!r}")
    return 0.5 * moving_mass(robot) + float(payload)


def reduced_mass(robot_mass: float, human_mass: float) -> float:
    """mu = (1/m_H + 1/m_R)^-1 [kg]; an infinite robot mass gives m_H."""
    if not (robot_mass > 0.0 and human_mass > 0.0):
        raise ConfigError(f"masses must be positive [kg]; got m_R={robot_mass!r}, m_H={human_mass!r}")
    return 1.0 / (1.0 / human_mass + (0.0 if math.isinf(robot_mass) else 1.0 / robot_mass))


def peak_transient_force(speed: float, robot_mass: float, region: str | BodyRegion) -> float:
    """F = v sqrt(mu k) [N]: the peak force of a transient contact at relative speed ``speed`` [m/s] of a mass
    ``robot_mass`` [kg] with the region's spring and mass (undamped two-mass model of A.3)."""
    r = body_region(region)
    return float(abs(speed)) * math.sqrt(reduced_mass(robot_mass, r.human_mass) * r.spring_constant_si)


def permissible_speed_for_mass(robot_mass: float, region: str | BodyRegion, force: float | None = None) -> float:
    """v_max = F / sqrt(mu k) [m/s] for a robot mass ``robot_mass`` [kg] and the region's transient limit F_T
    (or ``force`` [N])."""
    r = body_region(region)
    f = r.transient_force if force is None else float(force)
    if not (math.isfinite(f) and f > 0.0):
        raise ConfigError(f"force must be a positive limit [N]; got {force!r}")
    return f / math.sqrt(reduced_mass(robot_mass, r.human_mass) * r.spring_constant_si)


def permissible_speed(
    model: RobotModel,
    q: npt.ArrayLike,
    link: str,
    point: npt.ArrayLike,
    direction: npt.ArrayLike,
    region: str | BodyRegion,
) -> float:
    """The guard for your own trajectory generation: the largest relative speed [m/s] at which the point
    ``point`` (coordinates in frame ``link`` [m]) may hit the body region ``region`` moving along ``direction``
    (world) at posture ``q``, so that the transient contact force stays within the region's F_T
    (posture-dependent m_R(q, u), two-mass model of ISO/TS 15066 A.3).

    Example: scale a segment so that ``speed_along_u <= permissible_speed(robot, q, "link7", (0, 0, 0.1), u,
    "hand")`` at every sample.
    """
    return permissible_speed_for_mass(effective_mass(model, q, link, point, direction), region)


def contact_points(robot: RobotModel, points: Sequence[ContactPoint | str] | None = None) -> list[ContactPoint]:
    """The points to check: ``points`` (frame names or :class:`ContactPoint`), by default the end-effector
    frame and the origins of the frames of the last three joints (where a swinging arm is fastest)."""
    if points is None:
        names = [robot.ee_frame, *[j for j in robot.joint_names[-3:] if j in robot.frame_names]]
        return [ContactPoint(n) for n in dict.fromkeys(names)]
    out = [p if isinstance(p, ContactPoint) else ContactPoint(str(p)) for p in points]
    for p in out:
        robot.frame_id(p.link)  # ModelError naming the frames
    if not out:
        raise ConfigError("points must name at least one frame of the arm")
    return out
