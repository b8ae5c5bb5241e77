"""The collision event drawn into a rendered scene: the estimated contact force beside the true one.

A :class:`EventDrawing` holds what a still or a video frame at or after a detection shows of the event
(issue 15, item 6): an arrow of the estimated contact force at the estimated point (the controller's
``trace.meta["contact_estimate"]``, when point and force are determined), an arrow of the true force at the
true point (when the scene knows it: the force on the bodies beyond the wrist sensor, ``trace.f_ext_ee``, at
the end effector; the stick's contact force at its tip in the link push), and the text of the event
(class, reaction, phase, detection time; and why an arrow is missing). The arrows are MuJoCo's own scene
geoms (``mjv_initGeom`` / ``mjv_connector`` added to the ``MjvScene`` after ``mjv_updateScene``), so they
are lit, occluded and labelled like the rest of the scene.

An arrow ends at its point and points along the force on the arm (the push it shows), its length
:data:`FORCE_ARROW_SCALE` per newton within [:data:`MIN_ARROW_LENGTH`, :data:`MAX_ARROW_LENGTH`]; its label
sits at its tail.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant
    from reflexarm.sim.trace import Trace

__all__ = [
    "EventDrawing",
    "ForceArrow",
    "add_force_arrows",
    "detection_tick",
    "event_drawing",
    "rebuild_state",
    "side_azimuth",
]

#: Arrow length per newton [m/N]: 50 N draws 0.4 m, longer than MuJoCo's contact arrows in the stills.
FORCE_ARROW_SCALE = 0.008
#: Shortest and longest arrow drawn [m]: a 2 N estimate stays visible, a 500 N one stays in the picture.
MIN_ARROW_LENGTH = 0.1
MAX_ARROW_LENGTH = 0.6
#: Diameter of the event arrows [m] (thicker than the contact arrows' 0.012 m, so they stand out).
EVENT_ARROW_WIDTH = 0.025
#: Diameter of the sphere marking an arrow's point [m].
POINT_MARKER_SIZE = 0.03
#: Share of an ``mjGEOM_ARROW``'s ``size[2]`` that MuJoCo 4.0 draws (measured: ``mjv_connector`` sets
#: size[2] to the distance, and the arrow drawn ends halfway; a capsule from the same call spans it all).
#: tests/test_event_drawing.py renders both and checks that the arrow's tip meets the capsule's end.
ARROW_DRAWN_SHARE = 0.5
#: Height of the estimate's label above its arrow's tail, and of the truth's below [m].
LABEL_LIFT = 0.08
#: Colours (RGBA): the estimate magenta, the truth green (MuJoCo's contact arrows are orange-red).
ESTIMATE_RGBA = (0.95, 0.15, 0.85, 1.0)
TRUTH_RGBA = (0.1, 0.85, 0.2, 1.0)
#: Below this |force| [N] (|tau_ext| [Nm] for the stick) the true force counts as absent (no contact).
TRUE_FORCE_MIN_N = 1e-6
#: Singular values of the stick tip's Jacobian below this [m] count as zero: tau_ext then does not
#: determine the tip force (a proximal link moves the tip in fewer than 3 directions).
TIP_JACOBIAN_RANK_TOL = 1e-6
#: Characters per line of the overlay text (the corner band of a 640 px frame holds about 100).
TEXT_WIDTH = 95


@dataclass(frozen=True)
class ForceArrow:
    """A force on the arm drawn as an arrow ending at ``point``: point [m] and force [N] in the world frame,
    the label written beside its tail, raised by ``label_lift`` [m] (world z; the estimate's label above,
    the truth's below keep two arrows side by side readable), and its colour (RGBA in [0, 1])."""

    point: np.ndarray
    force: np.ndarray
    label: str
    rgba: tuple[float, float, float, float]
    label_lift: float = 0.0

    def __post_init__(self) -> None:
        for name in ("point", "force"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"ForceArrow.{name} must be 3 finite numbers; got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)

    @property
    def length(self) -> float:
        """The drawn length [m]: :data:`FORCE_ARROW_SCALE` |force|, clipped to the drawn range."""
        return min(max(FORCE_ARROW_SCALE * float(np.linalg.norm(self.force)), MIN_ARROW_LENGTH), MAX_ARROW_LENGTH)

    @property
    def direction(self) -> np.ndarray:
        """Unit vector of the force (the zero vector for a zero force)."""
        n = float(np.linalg.norm(self.force))
        return self.force / n if n > 0.0 else np.zeros(3)

    @property
    def tail(self) -> np.ndarray:
        """Where the arrow starts [m]: ``point - length * direction``."""
        return np.asarray(self.point - self.length * self.direction)


@dataclass(frozen=True)
class EventDrawing:
    """What a frame shows of a collision event: the arrows (estimate, truth; None when not known) and the
    text lines of the overlay (``notes`` say why an arrow is missing)."""

    t_detect: float
    estimate: ForceArrow | None
    truth: ForceArrow | None
    lines: tuple[str, ...]
    notes: tuple[str, ...] = ()

    @property
    def arrows(self) -> tuple[ForceArrow, ...]:
        return tuple(a for a in (self.estimate, self.truth) if a is not None)

    def text(self, width: int = TEXT_WIDTH) -> str:
        """The overlay: the lines and the notes, each wrapped at ``width`` characters."""
        return "\n".join(textwrap.fill(x, width, subsequent_indent="  ") for x in (*self.lines, *self.notes))


def add_force_arrows(scene: mujoco.MjvScene, arrows: Sequence[ForceArrow]) -> list[int]:
    """Append each arrow to ``scene``'s geoms: an ``mjGEOM_ARROW`` from its tail to its point, a sphere at its
    point and an ``mjGEOM_LABEL`` with its label beside the tail; returns the indices of the arrow geoms.
    Arrows that do not fit in the scene's ``maxgeom`` are left out (never an error: a picture must not fail)."""
    added: list[int] = []
    for arrow in arrows:
        if scene.ngeom + 3 > scene.maxgeom or not np.any(arrow.direction):
            continue
        rgba = np.asarray(arrow.rgba, dtype=np.float32)
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.eye(3).ravel(), rgba)
        mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, EVENT_ARROW_WIDTH, arrow.tail, arrow.point)
        g.size[2] = arrow.length / ARROW_DRAWN_SHARE  # so that the drawn arrow ends at the point
        added.append(scene.ngeom)
        scene.ngeom += 1
        s = scene.geoms[scene.ngeom]
        size = np.full(3, 0.5 * POINT_MARKER_SIZE)
        mujoco.mjv_initGeom(s, mujoco.mjtGeom.mjGEOM_SPHERE, size, arrow.point, np.eye(3).ravel(), rgba)
        scene.ngeom += 1
        t = scene.geoms[scene.ngeom]
        where = arrow.tail + np.array([0.0, 0.0, arrow.label_lift])
        mujoco.mjv_initGeom(t, mujoco.mjtGeom.mjGEOM_LABEL, np.zeros(3), where, np.eye(3).ravel(), rgba)
        t.label = arrow.label[:99]
        scene.ngeom += 1
    return added


# ------------------------------------------------------------------------ the event of a run, from its trace
def _fmt_time(x: Any) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{float(x):.3f} s"


def _estimate_arrow(estimate: dict[str, Any] | None) -> tuple[ForceArrow | None, str]:
    """(the estimate's arrow or None, the overlay line about it)."""
    if not estimate:
        return None, "estimate: none recorded for this run (no contact_estimate): no estimate arrow"
    link = estimate.get("link_name") or f"link {estimate.get('link')}"
    point, force = estimate.get("point"), estimate.get("force")
    if point is None or force is None:
        why = estimate.get("reason") or estimate.get("determined") or "point or force undetermined"
        size = "" if force is None else f", |f| = {float(np.linalg.norm(force)):.1f} N"
        return None, f"estimate: {link}{size}; no arrow: {why}"
    try:
        arrow = ForceArrow(point, force, f"estimate {float(np.linalg.norm(force)):.0f} N", ESTIMATE_RGBA, LABEL_LIFT)
    except ValueError as e:
        return None, f"estimate: {link}; no arrow: {e}"
    return arrow, f"estimate (magenta): {link}, |f| = {np.linalg.norm(arrow.force):.1f} N at detection"


def _pushed_body(trace: Trace, plant: Plant) -> str | None:
    """The arm body the scene pushes (the link push's ``pushed_body`` or placement ``body``), if known."""
    placement = trace.meta.get("placement")
    body = placement.get("body") if isinstance(placement, dict) else None
    body = body if body is not None else trace.meta.get("pushed_body")
    return body if isinstance(body, str) and body in plant.robot.frame_names else None


def _tip_force(trace: Trace, plant: Plant, k: int, tip: np.ndarray) -> tuple[np.ndarray | None, str]:
    """The stick's force on the arm at tick ``k``: the f with J_p(tip)^T f = tau_ext[k] (the plant's true
    external joint torque; one contact, at the stick's tip within its radius), or None and why."""
    robot = plant.robot
    body = _pushed_body(trace, plant)
    if body is None:
        return None, "the pushed link is not recorded"
    q = trace.q[k]
    J = robot.compute_frame_jacobian(q, body, world_aligned=True)
    origin = robot.compute_frame_pose(q, body)[1]
    r = tip - origin
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    Jp = J[:3] - skew @ J[3:]  # the tip's linear Jacobian
    rank = int(np.linalg.matrix_rank(Jp, tol=TIP_JACOBIAN_RANK_TOL))
    if rank < 3:
        return None, f"tau_ext does not determine the force at the tip of {body} (Jacobian rank {rank} < 3)"
    force, *_ = np.linalg.lstsq(Jp.T, trace.tau_ext[k], rcond=None)
    return force, f"from tau_ext at the stick tip on {body}"


def _truth_arrow(trace: Trace, plant: Plant, k: int) -> tuple[ForceArrow | None, str]:
    """(the true force's arrow at tick ``k`` or None, the overlay line about it)."""
    tips = sorted(key for key in trace.extras if key.endswith("_tip"))
    f_ee = np.asarray(trace.f_ext_ee[k], dtype=float)
    if np.linalg.norm(f_ee) > TRUE_FORCE_MIN_N:
        robot = plant.robot
        point = robot.compute_frame_pose(trace.q[k], robot.ee_frame)[1]
        label = f"true {np.linalg.norm(f_ee):.0f} N"
        line = f"true (green): |f_ext,EE| = {np.linalg.norm(f_ee):.1f} N at the end effector"
        return ForceArrow(point, f_ee, label, TRUTH_RGBA, label_lift=-LABEL_LIFT), line
    if tips:
        point = np.asarray(trace.extras[tips[0]][k], dtype=float)
        if float(np.abs(trace.tau_ext[k]).max()) <= TRUE_FORCE_MIN_N:
            return None, f"true: the stick does not touch the arm at t = {trace.t[k]:.3f} s: no true arrow"
        force, why = _tip_force(trace, plant, k, point)
        if force is None:
            return None, f"true: {why}: no true arrow"
        label = f"true {np.linalg.norm(force):.0f} N"
        line = f"true (green): {np.linalg.norm(force):.1f} N at the stick tip ({why})"
        return ForceArrow(point, force, label, TRUTH_RGBA, label_lift=-LABEL_LIFT), line
    return None, "true: no force beyond the wrist sensor and no recorded contact point at this moment: no true arrow"


def event_drawing(trace: Trace, plant: Plant, k: int) -> EventDrawing | None:
    """The event of ``trace`` drawn at its tick ``k`` (``plant``: the run's plant), or None when
    the run has no detection (``trace.meta["collision_event"]``) or ``k`` is before it. Never raises on a
    missing or malformed estimate or truth: the arrow is left out and a note says why."""
    event = trace.meta.get("collision_event")
    if not isinstance(event, dict) or event.get("t_detect") is None:
        return None
    t_detect = float(event["t_detect"])
    if trace.t[k] + 1e-9 < t_detect:
        return None
    joints = ", ".join(str(j) for j in event.get("joints_1based", []))
    mode = str(trace.mode[k]) if trace.mode.size > k else "?"
    lines = [
        f"EVENT {event.get('contact_class', '?')} detected at t = {_fmt_time(t_detect)} (joints {joints or '-'})",
        f"reaction: {event.get('reaction', '?')}, phase now: {mode} (at the end: {event.get('phase', '?')})",
    ]
    guard = str(event.get("text") or "")
    if guard:
        lines.append(f"guard: {guard}")
    elif event.get("guard_checked"):
        lines.append("guard: the arm came to rest")
    notes: list[str] = []
    estimate, line = _estimate_arrow(trace.meta.get("contact_estimate"))
    (lines if estimate is not None else notes).append(line)
    try:
        truth, line = _truth_arrow(trace, plant, k)
    except Exception as e:  # a picture never fails: say why the truth is missing
        truth, line = None, f"true: not drawn ({type(e).__name__}: {e})"
    (lines if truth is not None else notes).append(line)
    return EventDrawing(t_detect, estimate, truth, tuple(lines), tuple(notes))


def side_azimuth(drawing: EventDrawing, default: float) -> float:
    """A camera azimuth [deg] that looks across the drawing's force (the truth's, else the estimate's) so
    the arrows show their length: the horizontal direction of the force +-90 deg, the one nearer
    ``default``; ``default`` when the force is (nearly) vertical or there is no arrow."""
    arrows = [a for a in (drawing.truth, drawing.estimate) if a is not None]
    if not arrows:
        return default
    u = arrows[0].direction
    if math.hypot(u[0], u[1]) < 0.3:  # within ~17 deg of vertical: any side view shows it
        return default
    base = math.degrees(math.atan2(u[1], u[0]))
    return min((base + 90.0, base - 90.0), key=lambda a: abs((a - default + 180.0) % 360.0 - 180.0))


def detection_tick(trace: Trace) -> int | None:
    """The first tick with the collision flag, or None."""
    idx = np.flatnonzero(trace.collision)
    return None if idx.size == 0 else int(idx[0])


def rebuild_state(plant: Plant, base: mujoco.MjData, trace: Trace, k: int) -> mujoco.MjData:
    """``base`` (a state of the same run) moved to tick ``k`` of ``trace``: the arm's true q and dq, the clock,
    and the scene objects the trace records (a free body ``X`` from ``X_pos``/``X_quat``, joint ``X_free``;
    a mocap body ``X`` from ``X_tip``), then ``mj_forward``. What the trace does not record (a scene
    object's velocity, applied forces) stays as in ``base``."""
    m = plant.model
    data = mujoco.MjData(m)
    size = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_INTEGRATION)
    state = np.empty(size)
    mujoco.mj_getState(m, base, state, mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_setState(m, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
    data.time = float(trace.t[k])
    data.qpos[plant._qadr] = trace.q[k]
    data.qvel[plant._vadr] = trace.dq[k]
    for key, values in trace.extras.items():
        for suffix, width, offset in (("_pos", 3, 0), ("_quat", 4, 3)):
            if key.endswith(suffix):
                jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, key.removesuffix(suffix) + "_free")
                if jid >= 0 and np.shape(values)[1:] == (width,):
                    adr = int(m.jnt_qposadr[jid]) + offset
                    data.qpos[adr : adr + width] = values[k]
        if key.endswith("_tip"):
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, key.removesuffix("_tip"))
            if bid >= 0 and m.body_mocapid[bid] >= 0 and np.shape(values)[1:] == (3,):
                data.mocap_pos[m.body_mocapid[bid]] = values[k]
    mujoco.mj_forward(m, data)
    return data
