"""Classify and locate a detected collision from its event record: which link, where and how hard (the stages
isolate -> identify applied to :class:`~reflexarm.control.collision.event.CollisionEvent`), and whether the wrist
sensor measured it.

The real-time tick classifies at detection (measured end-effector contact vs collision, choosing the reaction);
isolation and identification of the contact from the residual at detection run here, in Python, right after the
detection (~ms to tens of ms per event; the C++ port runs in the core's process next). The residual at detection is
the observer's low-passed estimate of tau_ext: the force estimate is the force the residual had reached then,
not the contact's peak.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from reflexarm.control.collision.contact import ContactEstimate, sensor_estimate
from reflexarm.control.collision.event import CollisionEvent
from reflexarm.control.collision.isolate import RELATIVE_TOLERANCE, ContactIsolator
from reflexarm.errors import ConfigError
from reflexarm.robots.collision_geometry import CollisionGeometry, link_collision_geometry
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "CONTROLLER_SPACING",
    "SIGNIFICANCE_SHARE",
    "contact_geometry_args",
    "controller_geometry",
    "estimate_contact",
    "sensor_estimate",
]

#: Candidate point spacing of the controller's own isolation (in the real-time tick) [m]: 4x fewer points than the
#: isolation study's 1 cm (the C++ isolation of a detection then takes ~0.1-0.4 ms on Atlas, Panda, iiwa14); the
#: point estimate's resolution is half of it.
CONTROLLER_SPACING = 0.02

#: A residual component counts for isolation above this share of its detection threshold: at detection at least
#: one joint has crossed its threshold; the joints after the contact link carry only noise and model error, which
#: the thresholds (tuned above free-motion residuals) bound, so a quarter of them is above that floor on the arms
#: measured (free-motion residual levels of the isolation study: Atlas <= 2 Nm against 11 Nm thresholds). A first
#: choice, stated, not tuned on the study.
SIGNIFICANCE_SHARE = 0.25


def estimate_contact(
    robot: RobotModel,
    event: CollisionEvent,
    threshold: npt.ArrayLike,
    *,
    wrench: npt.ArrayLike | None = None,
    significance_share: float = SIGNIFICANCE_SHARE,
    isolator: ContactIsolator | None = None,
) -> ContactEstimate:
    """Contact link, point and force of a detected collision, from the residual and posture at detection.

    A contact the wrist sensor measured (``event.contact_class == "contact"``) is taken from the sensor when its
    ``wrench`` at detection is given: the link is the sensor's, the force the measured one (in the world frame),
    the point the one of the force's line of action closest to the sensor origin (the measured moment
    m = (p - o) x f fixes the line, not the point on it). Otherwise (a collision, or no wrench given) the joint
    residual is isolated (:class:`ContactIsolator`).

    Args:
        robot: the controller's model (the one that produced the residual).
        event: the collision event (:attr:`Controller.event`, or ``CollisionEvent.from_core``).
        threshold: the detection thresholds zeta [Nm] (scalar or (n,)).
        wrench: the wrist wrench at detection (6,) [N, Nm], in the sensor frame about its origin.
        significance_share: residual components above this share of the threshold count for isolation.
        isolator: a :class:`ContactIsolator` to reuse (its geometry is sampled once); default a new one.
    """
    if not (isinstance(significance_share, (int, float)) and 0.0 < significance_share <= 1.0):
        raise ConfigError(f"significance_share must be in (0, 1]; got {significance_share!r}")
    if event.contact_class == "contact" and wrench is not None:
        return _measured_contact(robot, event.q_detect, wrench)
    zeta = np.broadcast_to(np.asarray(threshold, dtype=float), (robot.n,))
    if isolator is None:
        isolator = ContactIsolator(robot, significance=significance_share * zeta)
    return isolator.isolate(event.q_detect, event.residual)


def _measured_contact(robot: RobotModel, q: np.ndarray, wrench: npt.ArrayLike) -> ContactEstimate:
    """The contact the wrist sensor measures: its link, the force in the world and a point of its line of action."""
    w = np.asarray(wrench, dtype=float)
    if w.shape != (6,) or not np.all(np.isfinite(w)):
        raise ConfigError(f"wrench must be 6 finite values (f, m) in the sensor frame; got {w!r}")
    rotation, position = robot.compute_frame_pose(q, robot.sensor_frame)
    f_s, m_s = w[:3], w[3:]
    f2 = float(f_s @ f_s)
    if f2 == 0.0:
        return ContactEstimate.none("the wrist sensor measures no force")
    offset = np.cross(f_s, m_s) / f2  # the point of the line of action closest to the sensor origin
    link = robot.pin_model.frames[robot.sensor_frame_id].parentJoint - 1
    return sensor_estimate(robot.sensor_frame, link, position + rotation @ offset, rotation @ f_s)


_GEOMETRY_CACHE: dict[tuple[object, ...], CollisionGeometry] = {}


def controller_geometry(robot: RobotModel, spacing: float = CONTROLLER_SPACING) -> CollisionGeometry | None:
    """The links' collision surfaces for a controller's isolation, sampled once per robot file, cut and kinematics
    (models that differ only in inertial parameters, e.g. with model errors, share it); None for a model without
    a robot file (built in memory: nothing to read the geometry from)."""
    if robot.source is None:
        return None
    model = robot.pin_model
    kinematics = tuple(
        (tuple(np.round(model.jointPlacements[j].homogeneous, 12).ravel()), model.names[j])
        for j in range(model.njoints)
    )
    key = (str(robot.source), repr(robot.cut), float(spacing), kinematics)
    geometry = _GEOMETRY_CACHE.get(key)
    if geometry is None:
        geometry = _GEOMETRY_CACHE[key] = link_collision_geometry(robot, spacing=spacing)
    return geometry


def contact_geometry_args(geometry: CollisionGeometry, share: float) -> tuple[object, ...]:
    """The arguments of the core's ``set_contact_geometry`` (the Controller's and the compiled loop's): per joint
    (m, 3) points and normals, the significance share and the isolator's defaults (those of
    :class:`ContactIsolator`)."""
    points = [np.ascontiguousarray(s.points, dtype=float).reshape(-1, 3) for s in geometry.links]
    normals = [np.ascontiguousarray(s.normals, dtype=float).reshape(-1, 3) for s in geometry.links]
    return points, normals, float(share), 0.0, RELATIVE_TOLERANCE, 0.5, 8
