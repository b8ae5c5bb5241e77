"""What happened after a collision, measured from a run's truth: one :class:`CollisionOutcome` per run.

The simulation knows what a real robot does not: when the scene first touched the arm (the true external
joint torque ``Trace.tau_ext`` and the true force on the bodies beyond the wrist sensor ``Trace.f_ext_ee``),
how hard, and how the arm moved (true ``q``, ``dq``). :func:`collision_outcome` turns a :class:`Trace` and
the plant's :class:`~reflexarm.robots.RobotModel` into the record the collision pipeline is judged by
(Haddadin et al., T-RO 2017: detection delay; the reaction by what the arm does after detection):

* contact: the first tick at which the plant's contact is counted, i.e. |f_ext_ee| > :data:`CONTACT_FORCE_N`
  or any |tau_ext_j| > :data:`CONTACT_TORQUE_NM` (the levels of :mod:`~reflexarm.experiments.collision_summary`);
* class: ``"end_effector"`` when the wrist sensor's bodies carry more than :data:`CONTACT_FORCE_N` between
  contact and detection (a contact the sensor measures), ``"link"`` otherwise (a collision only the joints
  feel), ``"none"`` without contact;
* force: |f_ext_ee| [N] (end-effector contacts; None for a link collision: the scenes record no contact
  force on a link, see :attr:`CollisionOutcome.contact_point`); external torque: max_j |tau_ext_j| [Nm]
  (every class);
* kinetic energy T = 1/2 dq^T M(q) dq [J] with the plant's M(q);
* moved after detection: the largest distance of the end effector (end-effector class) or of the contact
  link's origin (link class) from where it was at detection [m], and the largest |q_j - q_j(t_det)| [rad];
* re-contact: after detection the contact signal of the class (force for the end effector, external torque
  for a link; either for the class "none") falls below :data:`RELEASE_SHARE` of its level for at least
  :data:`RELEASE_MIN_S` (a release) and then rises above the level again (a settling contact that dips for a
  few ticks, or a resting one that sits at the level, is not a new strike).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError, DataError
from reflexarm.experiments.collision_summary import CONTACT_FORCE_N, CONTACT_TORQUE_NM, run_name
from reflexarm.robots import RobotModel
from reflexarm.sim import Trace

__all__ = [
    "CLASSES",
    "KE_RESIDUAL_SHARE",
    "KE_WINDOW_S",
    "RELEASE_MIN_S",
    "RELEASE_SHARE",
    "CollisionOutcome",
    "collision_outcome",
    "write_outcomes",
]

#: Contact classes: measured by the wrist sensor, felt by the joints only, no contact in the run.
CLASSES = ("end_effector", "link", "none")

#: The kinetic energy is reported this long after detection [s] (issue 15: "at detection and 0.5 s later").
KE_WINDOW_S = 0.5

#: The arm counts as stopped when its kinetic energy falls below this share of its value at detection.
KE_RESIDUAL_SHARE = 0.01

#: A contact signal must stay below :data:`RELEASE_SHARE` of its level this long [s] before a rise above the
#: level counts as a re-contact: longer than the few ticks a settling contact dips, far shorter than the time
#: an arm needs to leave a block and come back (hundreds of ms at < 1 m/s).
RELEASE_MIN_S = 0.02

#: The contact counts as released below this share of its level: a separation takes the true force to 0,
#: while a resting contact can sit at the level itself (the Atlas demo's Coll.Det run rests on the block with
#: 4.6-5.2 N after its reaction, crossing the 5 N level back and forth without leaving the block).
RELEASE_SHARE = 0.5


@dataclass(frozen=True)
class CollisionOutcome:
    """One run's collision event, measured from the simulation's truth (times [s], forces [N], torques [Nm],
    energies [J], distances [m], angles [rad]; joints 1-based). None: not applicable (e.g. no detection).

    Attributes:
        run: the run's name.
        contact_class: one of :data:`CLASSES`.
        contact_s: first tick of true contact.
        detected_s: first tick with the collision flag; None if never detected.
        delay_s: detected_s - contact_s (negative: detected before contact, a false alarm).
        joints_crossed: joints whose residual crossed the threshold at detection.
        contact_link: the link whose origin :attr:`moved_after_detection_m` follows for a link collision (the
            scene's pushed body from the run's metadata, else the link of the most distal joint with true
            external torque at contact); for an end-effector contact the end-effector frame.
        force_at_detection_N: |f_ext_ee| at detection (end-effector contacts).
        peak_force_after_detection_N: largest |f_ext_ee| after detection (end-effector contacts).
        peak_force_N: largest |f_ext_ee| in the run.
        external_torque_at_detection_Nm: max_j |tau_ext_j| at detection.
        peak_external_torque_after_detection_Nm: its largest value after detection.
        kinetic_energy_at_detection_J: T at detection.
        kinetic_energy_after_J: T at detection + :data:`KE_WINDOW_S` (None if the run ends earlier).
        kinetic_energy_ratio: kinetic_energy_after_J / kinetic_energy_at_detection_J.
        peak_kinetic_energy_after_detection_J: largest T after detection.
        stopped_after_s: time after detection at which T first falls below :data:`KE_RESIDUAL_SHARE` of its
            value at detection (None: never in the run).
        moved_after_detection_m: largest distance of the tracked point from its position at detection.
        away_at_end_m: how far from where it was at detection the contact point ends (the run's last sample): for
            a link collision whose scene records the point, that point fixed on the contact link; else the
            tracked frame's origin (the end effector for an end-effector contact). How far a retract took the
            arm from the contact.
        joint_travel_after_detection_rad: largest |q_j - q_j(t_det)| after detection, over joints.
        joint_travel_joint: the joint of that largest travel.
        peak_speed_ratio: largest |dq_j| / velocity limit_j after detection.
        peak_speed_joint: the joint of that largest ratio.
        peak_speed_rad_s: largest |dq_j| after detection (also for arms whose file gives no velocity limit).
        recontact: the contact came back after a release (module docstring).
        recontact_s: when it came back.
        peak_after_recontact: the largest contact signal after the re-contact (N for end-effector, Nm else).
        contact_point: the scene's truth of where it touches [m] (world) at detection, when the scene records
            one (the link push's stick tip, ``*_tip``: the end of the stick's centre line, within the stick's
            radius of the contact point); None otherwise (the cinderblock records only its pose).
        contact_point_source: which trace signal ``contact_point`` is.
        obstacle_advance_after_detection_m: how much further the scene's recorded obstacle (``*_tip``, the link
            push's stick) advanced after detection, along the way it had come since it appeared (the largest
            forward displacement of the tip from its place at detection while not parked); 0 for one that stands
            still (the held stick), None without a recorded tip. A reaction cannot keep away from an obstacle
            that advances further than it retreats.
    """

    run: str
    contact_class: str
    contact_s: float | None
    detected_s: float | None
    delay_s: float | None
    joints_crossed: tuple[int, ...]
    contact_link: str | None
    force_at_detection_N: float | None
    peak_force_after_detection_N: float | None
    peak_force_N: float
    external_torque_at_detection_Nm: float | None
    peak_external_torque_after_detection_Nm: float | None
    kinetic_energy_at_detection_J: float | None
    kinetic_energy_after_J: float | None
    kinetic_energy_ratio: float | None
    peak_kinetic_energy_after_detection_J: float | None
    stopped_after_s: float | None
    moved_after_detection_m: float | None
    away_at_end_m: float | None
    joint_travel_after_detection_rad: float | None
    joint_travel_joint: int | None
    peak_speed_ratio: float | None
    peak_speed_joint: int | None
    peak_speed_rad_s: float | None
    recontact: bool
    recontact_s: float | None
    peak_after_recontact: float | None
    contact_point: tuple[float, ...] | None
    contact_point_source: str | None
    obstacle_advance_after_detection_m: float | None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: tuples as lists."""
        out = asdict(self)
        for key in ("joints_crossed", "contact_point"):
            if out[key] is not None:
                out[key] = list(out[key])
        return out


def _first(mask: np.ndarray, start: int = 0) -> int | None:
    idx = np.flatnonzero(mask[start:])
    return None if idx.size == 0 else start + int(idx[0])


def _kinetic_energy(robot: RobotModel, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    return np.array([0.5 * v @ robot.compute_mass_matrix(p) @ v for p, v in zip(q, dq, strict=True)])


def _recontact(signal: np.ndarray, level: float, start: int, min_release: int) -> int | None:
    """Index of the first rise above ``level`` after the signal stayed below ``RELEASE_SHARE * level`` for
    ``min_release`` ticks, searching from ``start``; None if there is none."""
    released = False
    run = 0
    for k in range(start, signal.size):
        x = signal[k]
        if released and x > level:
            return k
        run = run + 1 if x < RELEASE_SHARE * level else 0
        released = released or run >= min_release
    return None


def _contact_link(trace: Trace, robot: RobotModel, i_contact: int) -> str:
    placement = trace.meta.get("placement")
    body = placement.get("body") if isinstance(placement, dict) else None
    if body is None:
        body = trace.meta.get("pushed_body")
    if isinstance(body, str) and body in robot.frame_names:
        return body
    from reflexarm.experiments.link_push import link_body

    k = int(np.flatnonzero(np.abs(trace.tau_ext[i_contact]) > CONTACT_TORQUE_NM).max())
    return link_body(robot, k + 1)[1]


def _contact_point(trace: Trace, i: int) -> tuple[tuple[float, ...] | None, str | None]:
    tips = sorted(k for k in trace.extras if k.endswith("_tip"))
    if not tips:
        return None, None
    p = np.asarray(trace.extras[tips[0]][i], dtype=float)
    return tuple(float(x) for x in p), tips[0]


#: A recorded tip below this height [m] is parked (ElbowStick waits 50 m below the scene), not in the scene.
PARKED_BELOW_Z = -10.0


def _obstacle_advance(trace: Trace, i_d: int) -> float | None:
    """:attr:`CollisionOutcome.obstacle_advance_after_detection_m` (None without a recorded tip)."""
    tips = sorted(k for k in trace.extras if k.endswith("_tip"))
    if not tips:
        return None
    tip = np.asarray(trace.extras[tips[0]], dtype=float)
    present = tip[:, 2] > PARKED_BELOW_Z
    if not present[i_d]:
        return None
    came = tip[i_d] - tip[int(np.flatnonzero(present)[0])]  # from where it appeared to where it is at detection
    norm = float(np.linalg.norm(came))
    after = tip[i_d:][present[i_d:]] - tip[i_d]
    if norm < 1e-9:  # it had not moved: any displacement after detection counts
        return float(np.linalg.norm(after, axis=1).max())
    return float(max(0.0, (after @ (came / norm)).max()))


def _after_detection(
    trace: Trace, robot: RobotModel, cls: str, link: str | None, force: np.ndarray, torque: np.ndarray, i_d: int
) -> dict[str, Any]:
    """The fields of :class:`CollisionOutcome` measured from detection (tick ``i_d``) on."""
    t = trace.t
    values: dict[str, Any] = {}
    after = slice(i_d + 1, None)
    has_after = i_d + 1 < len(t)
    ee_like = cls == "end_effector"
    values["force_at_detection_N"] = float(force[i_d]) if ee_like else None
    values["peak_force_after_detection_N"] = float(force[after].max()) if ee_like and has_after else None
    values["external_torque_at_detection_Nm"] = float(torque[i_d])
    values["peak_external_torque_after_detection_Nm"] = float(torque[after].max()) if has_after else None
    # kinetic energy from detection on
    ke = _kinetic_energy(robot, trace.q[i_d:], trace.dq[i_d:])
    t_after = t[i_d:] - t[i_d]
    values["kinetic_energy_at_detection_J"] = float(ke[0])
    k_w = _first(t_after >= KE_WINDOW_S - 1e-9)
    if k_w is not None:
        values["kinetic_energy_after_J"] = float(ke[k_w])
        values["kinetic_energy_ratio"] = float(ke[k_w] / ke[0]) if ke[0] > 0.0 else None
    values["peak_kinetic_energy_after_detection_J"] = float(ke[1:].max()) if has_after else None
    k_s = _first(ke < KE_RESIDUAL_SHARE * ke[0])
    values["stopped_after_s"] = None if k_s is None else float(t_after[k_s])
    # motion after detection
    frame = robot.ee_frame if link is None else link
    poses = [robot.compute_frame_pose(q, frame) for q in trace.q[i_d:]]
    p = np.array([x[1] for x in poses])
    values["moved_after_detection_m"] = float(np.linalg.norm(p - p[0], axis=1).max())
    point, _ = _contact_point(trace, i_d)
    if point is not None and cls == "link":  # the contact point, fixed on its link from detection on
        local = poses[0][0].T @ (np.asarray(point) - p[0])
        p = np.array([R @ local + x for R, x in poses])
    values["away_at_end_m"] = float(np.linalg.norm(p[-1] - p[0]))
    travel = np.abs(trace.q[i_d:] - trace.q[i_d]).max(axis=0)
    values["joint_travel_after_detection_rad"] = float(travel.max())
    values["joint_travel_joint"] = int(np.argmax(travel)) + 1
    values["peak_speed_rad_s"] = float(np.abs(trace.dq[i_d:]).max())
    vmax = robot.velocity_limit
    if np.all(np.isfinite(vmax)) and np.all(vmax > 0):
        ratio = (np.abs(trace.dq[i_d:]) / vmax).max(axis=0)
        values["peak_speed_ratio"] = float(ratio.max())
        values["peak_speed_joint"] = int(np.argmax(ratio)) + 1
    # re-contact
    if cls == "end_effector":
        signal, level = force, CONTACT_FORCE_N
    elif cls == "link":
        signal, level = torque, CONTACT_TORQUE_NM
    else:
        signal, level = np.maximum(force / CONTACT_FORCE_N, torque / CONTACT_TORQUE_NM), 1.0
    min_release = max(1, int(math.ceil(RELEASE_MIN_S / trace.dt - 1e-9)))
    i_r = _recontact(signal, level, i_d + 1, min_release)
    if i_r is not None:
        values.update(recontact=True, recontact_s=float(t[i_r]), peak_after_recontact=float(signal[i_r:].max()))
    return values


def collision_outcome(trace: Trace, robot: RobotModel, *, name: str | None = None) -> CollisionOutcome:
    """The collision event of one run, from its truth (module docstring).

    Args:
        trace: the run (true ``q``, ``dq``, ``f_ext_ee``, ``tau_ext``; the controller's ``collision``).
        robot: the plant's true model (M(q), frames and velocity limits), same joints as the trace.
        name: the run's name (default :func:`~reflexarm.experiments.collision_summary.run_name`).

    Raises:
        DataError: a trace of fewer than 2 samples, or whose joint count is not the robot's.
    """
    if not isinstance(trace, Trace):
        raise DataError(f"collision_outcome needs a Trace; got {type(trace).__name__}")
    if trace.t.size < 2:
        raise DataError(f"collision_outcome needs a trace of at least 2 samples; got {trace.t.size}")
    if trace.n != robot.n:
        raise DataError(f"the trace has {trace.n} joints; robot {robot.name!r} has {robot.n}")
    t = trace.t
    force = np.linalg.norm(trace.f_ext_ee, axis=1)
    torque = np.abs(trace.tau_ext).max(axis=1)
    touching = (force > CONTACT_FORCE_N) | (torque > CONTACT_TORQUE_NM)
    i_c = _first(touching)
    i_d = _first(trace.collision)
    end = len(t) if i_d is None else i_d + 1
    if i_c is None:
        cls = "none"
    elif np.any(force[i_c:end] > CONTACT_FORCE_N):
        cls = "end_effector"
    else:
        cls = "link"
    t_c = None if i_c is None else float(t[i_c])
    t_d = None if i_d is None else float(t[i_d])
    link: str | None = None
    if cls == "end_effector":
        link = robot.ee_frame
    elif cls == "link":
        link = _contact_link(trace, robot, int(i_c))  # type: ignore[arg-type]
    values: dict[str, Any] = {
        "run": name if name is not None else run_name(trace),
        "contact_class": cls,
        "contact_s": t_c,
        "detected_s": t_d,
        "delay_s": None if t_c is None or t_d is None else t_d - t_c,
        "joints_crossed": () if i_d is None else tuple(int(j) + 1 for j in np.flatnonzero(trace.collided[i_d])),
        "contact_link": link,
        "peak_force_N": float(force.max()),
        "recontact": False,
    }
    values.update(dict.fromkeys(f.name for f in fields(CollisionOutcome) if f.name not in values))
    if i_d is None:
        return CollisionOutcome(**values)
    values.update(_after_detection(trace, robot, cls, link, force, torque, i_d))
    point, source = _contact_point(trace, i_d)
    values["contact_point"], values["contact_point_source"] = point, source
    values["obstacle_advance_after_detection_m"] = _obstacle_advance(trace, i_d)
    return CollisionOutcome(**values)


def write_outcomes(outcomes: Sequence[CollisionOutcome | dict[str, Any]], path: str | Path) -> Path:
    """Write outcomes (or rows holding an outcome's fields and more, e.g. the study's arm and reaction) as
    ``.json`` (a list of objects) or ``.csv`` (one row each; lists joined by ';'). Returns the path.

    Raises:
        ConfigError: another file suffix.
    """
    p = Path(path)
    rows = [o.as_dict() if isinstance(o, CollisionOutcome) else dict(o) for o in outcomes]
    suffix = p.suffix.lower()
    if suffix not in (".json", ".csv"):
        raise ConfigError(f"unknown outcome file type {suffix!r} for {str(p)!r}; use .json or .csv")
    p.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".json":
        p.write_text(json.dumps(rows, indent=2))
        return p
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(p, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ";".join(str(x) for x in v) if isinstance(v, (list, tuple)) else v for k, v in r.items()})
    return p
