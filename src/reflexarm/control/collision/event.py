"""The record of one collision: what the stages detect -> isolate -> identify -> classify -> react found.

:attr:`reflexarm.control.Controller.event` returns it (filled by the real-time tick, ``cpp/src/reaction.cpp``).
The simulation's truth (time of contact, true force and point) is added beside it by
:mod:`reflexarm.experiments.collision_events`; a real robot has only this.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from reflexarm.control.collision.contact import ContactEstimate, sensor_estimate
from reflexarm.robots.collision_geometry import CollisionGeometry
from reflexarm.robots.robot_model import RobotModel

__all__ = ["CollisionEvent"]


@dataclass(frozen=True)
class CollisionEvent:
    """One detected collision (the reaction latches until :meth:`Controller.reset`).

    Attributes:
        t_detect: stamp of the detecting tick [s].
        joints: 0-based joints whose |residual| exceeded the threshold at detection.
        distal_joint: the most distal of them: a force on link i gives no torque on the joints after i, so the
            contact is on this joint's link or a later one (-1 if none).
        contact_class: ``"contact"`` (the wrist sensor measures it: an end-effector contact) or ``"collision"``
            (not measured: somewhere on the arm).
        reaction: the reaction chosen for this class (see :mod:`reflexarm.control.collision.react`).
        phase: where the reaction is now: ``"none"``, ``"gravity"``, ``"braking"``, ``"retracting"``,
            ``"holding"``.
        residual: the detection residual at detection (n,) [Nm].
        q_detect: posture at detection (n,) [rad].
        q_target: posture the reaction holds or retracts to (n,) [rad] (q_detect for gravity / none).
        retract_planned: retract: how far its plan moves the point it moves (the estimated point, the sensor frame,
            or, with the link only, the farthest-moving point from the link's far end on; NaN for other reactions) [m].
        wrist_force: |wrist force| at detection [N].
        peak_residual: largest max_i |residual_i| / threshold_i from detection on [-].
        energy_detect: kinetic energy 0.5 dq_f^T (M(q) dq)_f at detection, from the measured dq and M dq low-passed
            with ``ReactionSettings.energy_filter_time`` [J].
        energy_rest: the same ``rest_time`` after detection (NaN until then) [J].
        energy_max: largest kinetic energy from detection on [J].
        moved: largest joint displacement from q_detect since detection [rad].
        t_hold: stamp the reaction started holding a posture (NaN: not (yet)) [s].
        recrossings: detections again after the residual had fallen below every threshold (re-contacts).
        torque_limited: the reaction's torque hit the torque limit on some tick.
        overspeed: some joint exceeded its velocity limit during the reaction.
        still_moving: the guard found the arm moving ``rest_time`` after detection (see ``text``).
        text: the guard's report, "" if the reaction brought the arm to rest (or it has not run yet).
        estimate: where and how hard, at detection (:class:`~reflexarm.control.collision.contact.ContactEstimate`):
            the wrist sensor's measurement for a measured contact, else the isolation of the residual in the tick
            (when the controller has the links' collision geometry); None without one.
        t_estimate: stamp of the residual the isolation used (``isolation_delay`` after detection) [s].
        t_estimated: stamp of the tick the isolation finished, its estimate in use from then on (it is spread over
            the ticks: ``ReactionSettings.isolation_points_per_tick``; = t_estimate if it had no work; NaN, as
            t_estimate, for the wrist sensor's estimate) [s].
    """

    t_detect: float
    joints: tuple[int, ...]
    distal_joint: int
    contact_class: str
    reaction: str
    phase: str
    residual: np.ndarray
    q_detect: np.ndarray
    q_target: np.ndarray
    retract_planned: float
    wrist_force: float
    peak_residual: float
    energy_detect: float
    energy_rest: float
    energy_max: float
    moved: float
    t_hold: float
    recrossings: int
    torque_limited: bool
    overspeed: bool
    still_moving: bool
    guard_checked: bool
    text: str
    estimate: ContactEstimate | None = None
    t_estimate: float = float("nan")
    t_estimated: float = float("nan")

    @classmethod
    def from_core(
        cls, record: dict[str, Any], *, geometry: CollisionGeometry | None = None, robot: RobotModel | None = None
    ) -> CollisionEvent | None:
        """The event from the core's record (``reflexarm._core.Controller.event``); None before a detection.
        ``geometry`` (the surfaces the core isolates on) and ``robot`` (for the sensor frame's name) give the
        estimate its names and reason text."""
        if not record["detected"]:
            return None
        values = {k: v for k, v in record.items() if k not in ("detected", "estimate", "estimate_from_sensor")}
        values["t_estimate"] = float(record.get("t_estimate", float("nan")))
        values["t_estimated"] = float(record.get("t_estimated", float("nan")))
        values["estimate"] = _estimate(record, geometry, robot)
        values["joints"] = tuple(int(i) for i in np.flatnonzero(np.asarray(record["joints"])))
        for key in ("residual", "q_detect", "q_target"):
            values[key] = np.array(record[key], dtype=float)
        return cls(**values)

    @classmethod
    def from_dict(cls, record: dict[str, Any]) -> CollisionEvent:
        """The event back from :meth:`to_dict` (e.g. a trace's ``meta["collision_event"]``)."""
        values: dict[str, Any] = {f.name: record.get(f.name) for f in fields(cls)}
        if values["estimate"] is not None:
            values["estimate"] = ContactEstimate.from_dict(values["estimate"])
        values["joints"] = tuple(int(j) for j in record["joints"])
        for key in ("residual", "q_detect", "q_target"):
            values[key] = np.asarray(record[key], dtype=float)
        for f in fields(cls):
            if f.type == "float" and values[f.name] is None:
                values[f.name] = math.nan
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: arrays as lists, NaN as None, joints 1-based under ``joints_1based`` beside the 0-based."""
        out: dict[str, Any] = {}
        for key, value in asdict(self).items():
            if key == "estimate":
                value = None if self.estimate is None else self.estimate.as_dict()
            elif isinstance(value, np.ndarray):
                value = value.tolist()
            elif isinstance(value, float) and not math.isfinite(value):
                value = None
            elif isinstance(value, tuple):
                value = list(value)
            out[key] = value
        out["joints_1based"] = [j + 1 for j in self.joints]
        return out


def _estimate(
    record: dict[str, Any], geometry: CollisionGeometry | None, robot: RobotModel | None
) -> ContactEstimate | None:
    out = record.get("estimate")
    if out is None:
        return None
    if record.get("estimate_from_sensor"):  # the sensor frame unnamed when there is no robot to name it
        frame = "" if robot is None else robot.sensor_frame
        return sensor_estimate(frame, int(out["link"]), out["point"], out["force"])
    if geometry is None:
        return None
    from reflexarm.control.collision.isolate_core import estimate_from_core

    return estimate_from_core(out, geometry)
