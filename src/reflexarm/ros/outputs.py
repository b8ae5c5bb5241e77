"""The messages the collision node publishes, built from the controller's results.

- the residual: ``sensor_msgs/JointState`` with the joints' names and the residual torque in ``effort`` [Nm],
  stamped with the input's stamp (derived messages keep the input stamp);
- a collision event: one ``diagnostic_msgs/DiagnosticStatus`` (level ERROR) per event, with the link, the force,
  the delays and the joints as ``KeyValue`` strings;
- the estimated contact wrench: ``geometry_msgs/WrenchStamped`` in the base frame, about its origin;
- the contact arrow: ``visualization_msgs/Marker`` ARROW from ``force * ARROW_M_PER_N`` before the contact point
  to the point, in the base frame;
- the effort command: ``std_msgs/Float64MultiArray``, ``data[i]`` for the robot's joint i, as ros2_control's
  forward command controller reads it (``joints[i]/effort``), the layout left empty.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import Marker

from reflexarm.control.collision.event import CollisionEvent

__all__ = ["ARROW_M_PER_N", "contact_marker", "contact_wrench", "effort_command", "event_status", "residual_state"]

#: Length of the contact arrow per newton [m/N] (100 N: 0.2 m), capped at 0.5 m.
ARROW_M_PER_N = 0.002

LEVEL_OK, LEVEL_WARN, LEVEL_ERROR, LEVEL_STALE = (bytes([i]) for i in range(4))


def effort_command(tau: np.ndarray) -> Float64MultiArray:
    """The forward command controller's message: one effort per joint, the robot's joint order [Nm]."""
    msg = Float64MultiArray()
    msg.data = tau.tolist()
    return msg


def residual_state(stamp: Any, names: Sequence[str], residual: np.ndarray, msg: JointState | None = None) -> JointState:
    """The residual [Nm] as a JointState (``effort``), stamped with the input's stamp; ``msg``: a message of the
    same joints to fill again (its names are kept: setting them is a good part of the cost at 1 kHz)."""
    if msg is None:
        msg = JointState()
        msg.name = list(names)
    msg.header.stamp = stamp
    msg.effort = residual.tolist()
    return msg


def _fmt(value: float, unit: str = "") -> str:
    return "nan" if not math.isfinite(value) else f"{value:.6g}{unit}"


def event_status(
    number: int, event: CollisionEvent, *, node: str, hardware_id: str, t0_ns: int, onset_delay: float
) -> DiagnosticStatus:
    """The event's status: ``name`` ``"<node>: collision <number>"``, level ERROR, a one-line message and the
    values: time (stamp of the detecting tick, and seconds since the first stamp), joints (1-based), class,
    reaction, link, force [N], contact point [m], delays [s] and the peak residual."""
    est = event.estimate
    force = est.force if est is not None and est.force is not None else None
    f_norm = float(np.linalg.norm(force)) if force is not None else math.nan
    link = est.link_name if est is not None and est.link >= 0 else ""
    where = link or f"link of joint {event.distal_joint + 1} or a later one"
    status = DiagnosticStatus()
    status.level = LEVEL_ERROR
    status.name = f"{node}: collision {number}"
    status.hardware_id = hardware_id
    status.message = (
        f"{event.contact_class} detected at t = {event.t_detect:.3f} s on {where}"
        + (f", |f| = {f_norm:.1f} N" if force is not None else ", force not estimated yet")
        + f"; reaction {event.reaction}"
    )
    stamp_ns = t0_ns + int(round(event.t_detect * 1e9))
    values = {
        "stamp_ns": str(stamp_ns),
        "t_detect_s": _fmt(event.t_detect),
        "joints": ",".join(str(j + 1) for j in event.joints),
        "class": event.contact_class,
        "reaction": event.reaction,
        "link": link,
        "link_index": str(est.link + 1 if est is not None and est.link >= 0 else event.distal_joint + 1),
        "force_N": _fmt(f_norm),
        "force_xyz_N": "" if force is None else ",".join(f"{v:.4g}" for v in force),
        "point_xyz_m": "" if est is None or est.point is None else ",".join(f"{v:.4g}" for v in est.point),
        "delay_s": _fmt(onset_delay),
        "estimate_delay_s": _fmt(event.t_estimated - event.t_detect),
        "peak_residual": _fmt(event.peak_residual),
        "determined": "" if est is None else str(est.determined),
    }
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return status


def contact_wrench(stamp: Any, frame: str, event: CollisionEvent) -> WrenchStamped | None:
    """The estimated contact force and its moment about the base frame's origin (None without a force)."""
    est = event.estimate
    if est is None or est.force is None:
        return None
    msg = WrenchStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    f = np.asarray(est.force, dtype=float)
    m = np.cross(est.point, f) if est.point is not None else np.zeros(3)
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = (float(v) for v in f)
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (float(v) for v in m)
    return msg


def contact_marker(stamp: Any, frame: str, ns: str, event: CollisionEvent | None) -> Marker:
    """An ARROW pointing at the contact point along the force (or a DELETE of it: ``event`` None or no point)."""
    msg = Marker()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.ns = ns
    msg.id = 0
    est = None if event is None else event.estimate
    if est is None or est.point is None or est.force is None:
        msg.action = Marker.DELETE
        return msg
    msg.type = Marker.ARROW
    msg.action = Marker.ADD
    f = np.asarray(est.force, dtype=float)
    norm = float(np.linalg.norm(f))
    length = min(0.5, ARROW_M_PER_N * norm)
    tip = np.asarray(est.point, dtype=float)
    tail = tip - (f / norm * length if norm > 0 else 0.0)
    msg.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in (tail, tip)]
    msg.pose.orientation.w = 1.0
    msg.scale.x, msg.scale.y, msg.scale.z = 0.01, 0.02, 0.03
    msg.color.r, msg.color.g, msg.color.b, msg.color.a = 1.0, 0.1, 0.1, 1.0
    return msg
