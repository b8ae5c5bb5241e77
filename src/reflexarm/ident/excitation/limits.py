"""What an excitation trajectory must respect: joint limits, joint torques, a workspace bound, self-collision.

:class:`ExcitationLimits` bundles the bounds; :class:`LimitEvaluator` evaluates them along a motion, with
the derivatives the optimizer needs (:mod:`.design`) and as a per-sample report for the export
(:mod:`.export`). Each bound, evaluated at a configuration (q, dq, ddq):

* **torque**: the torque the model needs, ``tau = RNEA(q, dq, ddq) + d_v dq + mu_C sgn(dq)`` (rigid body
  of the robot file plus its friction), within ``max_torque`` (default a fraction
  :data:`DEFAULT_TORQUE_FRACTION` of the file's effort limit: the controller adds its feedback and the
  model is not exact);
* **workspace**: every point of the arm's collision surface at least ``clearance`` above the plane
  ``z = floor`` of the base frame (a floor or table the user names; by default the base plane z = 0 when
  the arm stands on it, see :func:`default_floor`);
* **self-collision**: each pair of links at least two joints apart (adjacent links touch at their joint)
  kept ``clearance`` apart, links approximated by **capsules** fitted to the MuJoCo collision geometry
  of the robot file (:func:`reflexarm.robots.link_collision_geometry`: a segment along each link's
  principal axis, with the radius that contains all its surface points). Pairs that already overlap at
  the reference pose (e.g. the links of a compact spherical wrist, whose capsules are coarse) are not
  checked and are listed in :attr:`ArmGeometry.excluded`.

The workspace bound uses the sampled surface points themselves (every ``POINT_SPACING``), the
self-collision check the capsules.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DEFAULT_CLEARANCE",
    "DEFAULT_TORQUE_FRACTION",
    "ArmGeometry",
    "ExcitationLimits",
    "LimitEvaluator",
    "arm_geometry",
    "default_floor",
]

#: Share of the robot file's effort limit an excitation may ask of the model. The controller that plays
#: it adds feedback on top of the feedforward, and the model's torques are off by its error (+-10 % in the
#: simulated study): 0.8 leaves 20 % of the limit for both. (The issue's recorded run sat at >= 97 % of
#: a joint's limit 34 % of the time when the design asked up to 102 %.)
DEFAULT_TORQUE_FRACTION = 0.8
#: Distance kept from the floor and between links [m]: 2 cm, twice the collision geometry's sampling.
DEFAULT_CLEARANCE = 0.02
#: Spacing of the surface points checked against the floor [m].
POINT_SPACING = 0.02


@dataclass(frozen=True)
class ExcitationLimits:
    """Bounds of an excitation, per joint (n,) unless said otherwise.

    Attributes:
        lower, upper: position range [rad] (the robot's minus the margin).
        max_velocity [rad/s], max_acceleration [rad/s^2], max_torque [Nm] (inf: unbounded).
        floor: height of the plane no point of the arm may go below, in the base frame [m]; None: none.
        clearance: distance kept from the floor and between links [m].
        self_collision: whether links are kept apart.
        notes: how the bounds were chosen (printed by ``reflexarm excite``).
    """

    lower: np.ndarray
    upper: np.ndarray
    max_velocity: np.ndarray
    max_acceleration: np.ndarray
    max_torque: np.ndarray
    floor: float | None = None
    clearance: float = DEFAULT_CLEARANCE
    self_collision: bool = True
    notes: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, object]:
        """JSON-ready (infinite torque bounds as None)."""
        return {
            "lower": self.lower.tolist(),
            "upper": self.upper.tolist(),
            "max_velocity": self.max_velocity.tolist(),
            "max_acceleration": self.max_acceleration.tolist(),
            "max_torque": [float(x) if np.isfinite(x) else None for x in self.max_torque],
            "floor": self.floor,
            "clearance": self.clearance,
            "self_collision": self.self_collision,
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class ArmGeometry:
    """The arm's collision geometry as the limits use it (see the module docstring).

    Attributes:
        points: per joint, surface points (m_j, 3) in the Pinocchio joint frame [m] (the joint origin alone
            for a link without collision geometry).
        capsules: per joint, (a, b, radius) in the joint frame, or None without geometry.
        pairs: (i, j) joint pairs whose links are kept apart; excluded: pairs overlapping at the reference pose.
    """

    points: tuple[np.ndarray, ...]
    capsules: tuple[tuple[np.ndarray, np.ndarray, float] | None, ...]
    pairs: tuple[tuple[int, int], ...]
    excluded: tuple[tuple[int, int], ...]


def _to_world(M: pin.SE3, points: np.ndarray) -> np.ndarray:
    """Points (m, 3) of a joint frame in the world frame."""
    return points @ np.asarray(M.rotation).T + np.asarray(M.translation)


def _fit_capsule(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The segment along the points' principal axis and the radius that contains them all."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    axis = vt[0]
    t = (points - c) @ axis
    a, b = c + t.min() * axis, c + t.max() * axis
    return a, b, float(np.max(_point_segment_distance(points, a, b)))


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    s = np.clip((p - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def arm_geometry(robot: RobotModel, q_reference: np.ndarray, *, clearance: float = DEFAULT_CLEARANCE) -> ArmGeometry:
    """Surface points and capsules of ``robot``'s links from its file's MuJoCo collision geometry; the pairs
    at least two joints apart that are clear of each other at ``q_reference`` are kept apart."""
    from reflexarm.robots.collision_geometry import link_collision_geometry

    surfaces = link_collision_geometry(robot, spacing=POINT_SPACING)
    points, capsules = [], []
    for s in surfaces.links:
        points.append(s.points if s.has_geometry else np.zeros((1, 3)))
        capsules.append(_fit_capsule(s.points) if s.size >= 2 else None)
    pairs: list[tuple[int, int]] = []
    excluded: list[tuple[int, int]] = []
    world = _capsules_in_world(robot.pin_model, q_reference, capsules)
    for i in range(robot.n):
        for j in range(i + 2, robot.n):
            wi, wj = world[i], world[j]
            if wi is None or wj is None:
                continue
            d = _capsule_distance(wi, wj)[0]
            (pairs if d > clearance else excluded).append((i, j))
    return ArmGeometry(tuple(points), tuple(capsules), tuple(pairs), tuple(excluded))


def _capsules_in_world(
    model: pin.Model, q: np.ndarray, capsules: list[tuple[np.ndarray, np.ndarray, float] | None]
) -> list[tuple[np.ndarray, np.ndarray, float] | None]:
    data = model.createData()
    pin.forwardKinematics(model, data, np.asarray(q, dtype=float))
    out: list[tuple[np.ndarray, np.ndarray, float] | None] = []
    for j, cap in enumerate(capsules):
        if cap is None:
            out.append(None)
            continue
        M = data.oMi[j + 1]
        out.append((M.act(cap[0]), M.act(cap[1]), cap[2]))
    return out


def _capsule_distance(
    A: tuple[np.ndarray, np.ndarray, float], B: tuple[np.ndarray, np.ndarray, float]
) -> tuple[float, np.ndarray, np.ndarray]:
    """Surface distance of two capsules and the closest points of their segments (world frame)."""
    p, q = _closest_points(A[0], A[1], B[0], B[1])
    return float(np.linalg.norm(p - q)) - A[2] - B[2], p, q


def _closest_points(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of segments a0-a1 and b0-b1 (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    if a <= 1e-18 and e <= 1e-18:
        return a0, b0
    if a <= 1e-18:
        return a0, b0 + np.clip(f / e, 0.0, 1.0) * d2
    c = float(d1 @ r)
    if e <= 1e-18:
        return a0 + np.clip(-c / a, 0.0, 1.0) * d1, b0
    b = float(d1 @ d2)
    den = a * e - b * b
    s = np.clip((b * f - c * e) / den, 0.0, 1.0) if den > 1e-18 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, np.clip(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t, s = 1.0, np.clip((b - c) / a, 0.0, 1.0)
    return a0 + s * d1, b0 + t * d2


def default_floor(robot: RobotModel, geometry: ArmGeometry, q_reference: np.ndarray) -> tuple[float | None, str]:
    """The base plane z = 0 if the arm at ``q_reference`` lies above it (an arm standing on its base);
    None for an arm that reaches below it there (e.g. hanging from a torso): (floor, a sentence why)."""
    data = robot.pin_model.createData()
    pin.forwardKinematics(robot.pin_model, data, np.asarray(q_reference, dtype=float))
    lowest = min(float(np.min(_to_world(data.oMi[j + 1], p)[:, 2])) for j, p in enumerate(geometry.points))
    if lowest >= 0.0:
        return 0.0, f"workspace: no point of the arm below the base plane z = 0 (at the centre pose: {lowest:.3f} m)"
    return None, (
        f"workspace: no floor (the arm reaches {lowest:.3f} m below its base plane at the centre pose: it does not "
        "stand on it); name one with --floor Z"
    )


class LimitEvaluator:
    """The torque, workspace and self-collision bounds along a motion (see the module docstring).

    Margins are scaled to O(1) and >= 0 inside: ``(max_torque -+ tau) / max_torque``,
    ``(z - floor - clearance) / SCALE`` and ``(distance - clearance) / SCALE`` with SCALE = 0.1 m.
    """

    SCALE = 0.1  # [m]

    def __init__(self, robot: RobotModel, limits: ExcitationLimits, geometry: ArmGeometry | None) -> None:
        self.robot = robot
        self.limits = limits
        self.geometry = geometry
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.viscous = np.asarray(robot.friction.viscous, dtype=float)
        self.coulomb = np.asarray(robot.friction.coulomb, dtype=float)
        self.torque_joints = np.flatnonzero(np.isfinite(limits.max_torque))
        self.use_floor = geometry is not None and limits.floor is not None
        self.pairs = geometry.pairs if (geometry is not None and limits.self_collision) else ()
        self._last_poses: tuple[bytes, np.ndarray, np.ndarray] | None = None

    @property
    def active(self) -> bool:
        """Whether any of the three bounds applies."""
        return bool(self.torque_joints.size or self.use_floor or self.pairs)

    def torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """The model's torque (N, n) [Nm] (rigid body + friction) along samples (N, n)."""
        tau = np.empty_like(q)
        for k in range(q.shape[0]):
            tau[k] = pin.rnea(self.model, self.data, q[k], dq[k], ddq[k])
        return tau + self.viscous * dq + self.coulomb * np.sign(dq)

    def margins(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, Gq: np.ndarray, Gv: np.ndarray, Ga: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Scaled margins (m,) over samples (N, n) and their derivative (m, p) with respect to the
        optimizer's variables x, given the linear maps q = Gq[k] x + ..., each (N, n, p)."""
        values: list[np.ndarray] = []
        rows: list[np.ndarray] = []
        tj, tmax = self.torque_joints, self.limits.max_torque[self.torque_joints]
        for k in range(q.shape[0]):
            m, data = self.model, self.data
            if tj.size:
                pin.computeRNEADerivatives(m, data, q[k], dq[k], ddq[k])
                tau = data.tau + self.viscous * dq[k] + self.coulomb * np.sign(dq[k])
                dtau = data.dtau_dq @ Gq[k] + (data.dtau_dv + np.diag(self.viscous)) @ Gv[k] + data.M @ Ga[k]
                M_full = np.triu(data.M) + np.triu(data.M, 1).T
                dtau += (M_full - data.M) @ Ga[k]  # Pinocchio fills only the upper triangle of M
                values += [(tmax - tau[tj]) / tmax, (tmax + tau[tj]) / tmax]
                rows += [-dtau[tj] / tmax[:, None], dtau[tj] / tmax[:, None]]
            if self.use_floor or self.pairs:
                pin.computeJointJacobians(m, data, q[k])
            if self.use_floor:
                v, r = self._floor(data, Gq[k])
                values.append(v)
                rows.append(r)
            for i, j in self.pairs:
                v1, r1 = self._pair(data, i, j, Gq[k])
                values.append(np.array([v1]))
                rows.append(r1[None, :])
        return np.concatenate(values), np.vstack(rows)

    def _point_velocity_rows(self, data: pin.Data, joint: int, point_world: np.ndarray) -> np.ndarray:
        """d(point)/dq (3, n) of a point rigidly carried by ``joint`` (0-based)."""
        J = pin.getJointJacobian(self.model, data, joint + 1, pin.LOCAL_WORLD_ALIGNED)
        r = point_world - data.oMi[joint + 1].translation
        return J[:3] - np.cross(r[None, :], J[3:].T).T  # v + w x r = v - r x w

    def _floor(self, data: pin.Data, Gq_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        assert self.geometry is not None and self.limits.floor is not None
        values, rows = [], []
        for j, pts in enumerate(self.geometry.points):
            world = _to_world(data.oMi[j + 1], pts)
            low = int(np.argmin(world[:, 2]))
            dz = self._point_velocity_rows(data, j, world[low])[2]
            values.append((world[low, 2] - self.limits.floor - self.limits.clearance) / self.SCALE)
            rows.append(dz @ Gq_k / self.SCALE)
        return np.array(values), np.vstack(rows)

    def _pair(self, data: pin.Data, i: int, j: int, Gq_k: np.ndarray) -> tuple[float, np.ndarray]:
        assert self.geometry is not None
        ci, cj = self.geometry.capsules[i], self.geometry.capsules[j]
        assert ci is not None and cj is not None
        A = (data.oMi[i + 1].act(ci[0]), data.oMi[i + 1].act(ci[1]), ci[2])
        B = (data.oMi[j + 1].act(cj[0]), data.oMi[j + 1].act(cj[1]), cj[2])
        d, p, pq = _capsule_distance(A, B)
        normal = (p - pq) / max(float(np.linalg.norm(p - pq)), 1e-12)
        grad = normal @ (self._point_velocity_rows(data, i, p) - self._point_velocity_rows(data, j, pq))
        return (d - self.limits.clearance) / self.SCALE, grad @ Gq_k / self.SCALE

    def margin_samples(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """The scaled margins of :meth:`margins` at every sample, (N, m) (one row per sample, >= 0 inside; the
        columns need not follow :meth:`margins`' order), without derivatives: for a dense check."""
        columns: list[np.ndarray] = []
        if self.torque_joints.size:
            tj = self.torque_joints
            tmax = self.limits.max_torque[tj]
            tau = self.torque(q, dq, ddq)[:, tj]
            columns += [(tmax - tau) / tmax, (tmax + tau) / tmax]
        if self.use_floor or self.pairs:
            assert self.geometry is not None
            R, p = self._poses(q)
            if self.use_floor:
                assert self.limits.floor is not None
                z = np.stack([np.min(R[:, j, 2, :] @ pts.T + p[:, j, 2:3], axis=1) for j, pts in
                              enumerate(self.geometry.points)], axis=1)  # fmt: skip
                columns.append((z - self.limits.floor - self.limits.clearance) / self.SCALE)
            if self.pairs:
                d = self._pair_distances(R, p)
                columns.append((d.T - self.limits.clearance) / self.SCALE)
        return np.concatenate(columns, axis=1) if columns else np.zeros((q.shape[0], 0))

    def _pair_distances(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Surface distances (pairs, N) [m] of the kept-apart capsule pairs, given the joint poses of :meth:`_poses`."""
        assert self.geometry is not None
        ends = {}
        for j, cap in enumerate(self.geometry.capsules):
            if cap is not None:
                ends[j] = (R[:, j] @ cap[0] + p[:, j], R[:, j] @ cap[1] + p[:, j], cap[2])
        return np.stack(
            [_segment_distances(*ends[i][:2], *ends[j][:2]) - ends[i][2] - ends[j][2] for i, j in self.pairs]
        )

    def report(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict[str, dict[str, Any]]:
        """Per bound, its worst sample: ``{"torque": {"use", "joint", "time", "value", "limit"}, "workspace":
        {"clearance_m", "joint", "time"}, "self_collision": {"clearance_m", "pair", "time"}}`` (only the bounds
        that apply; use <= 1 and clearances >= 0 are within)."""
        out: dict[str, dict[str, Any]] = {}
        if self.torque_joints.size:
            tau = self.torque(q, dq, ddq)
            use = np.abs(tau[:, self.torque_joints]) / self.limits.max_torque[self.torque_joints]
            ks, cs = np.unravel_index(int(np.argmax(use)), use.shape)
            j = int(self.torque_joints[cs])
            out["torque"] = {"use": float(use[ks, cs]), "joint": j, "time": float(t[ks]),
                             "value": float(tau[ks, j]), "limit": float(self.limits.max_torque[j])}  # fmt: skip
        if not (self.use_floor or self.pairs):
            return out
        assert self.geometry is not None
        R, p = self._poses(q)
        if self.use_floor:
            assert self.limits.floor is not None
            z = np.stack(
                [np.min(R[:, j, 2, :] @ pts.T + p[:, j, 2:3], axis=1) for j, pts in enumerate(self.geometry.points)]
            )
            jz, kz = np.unravel_index(int(np.argmin(z)), z.shape)
            out["workspace"] = {"clearance_m": float(z[jz, kz]) - self.limits.floor, "joint": int(jz),
                                "time": float(t[kz])}  # fmt: skip
        if self.pairs:
            d = self._pair_distances(R, p)
            c, k = np.unravel_index(int(np.argmin(d)), d.shape)
            out["self_collision"] = {"clearance_m": float(d[c, k]), "pair": self.pairs[c], "time": float(t[k])}
        return out

    def _poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (N, n, 3, 3) and origins (N, n, 3) of the joint frames along samples q (N, n); the last
        call's are kept (the 1 kHz check asks :meth:`margin_samples` and :meth:`report` of one motion)."""
        key = q.tobytes()
        if self._last_poses is None or self._last_poses[0] != key:
            self._last_poses = (key, *self._compute_poses(q))
        return self._last_poses[1], self._last_poses[2]

    def _compute_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        N, n = q.shape
        R, p = np.empty((N, n, 3, 3)), np.empty((N, n, 3))
        for k in range(N):
            pin.forwardKinematics(self.model, self.data, q[k])
            for j in range(n):
                M = self.data.oMi[j + 1]
                R[k, j], p[k, j] = M.rotation, M.translation
        return R, p


def _segment_distances(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Distances (N,) between segments a0-a1 and b0-b1, each end (N, 3): :func:`_closest_points` vectorised
    (segments of non-zero length, which fitted capsules have)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e = np.einsum("ij,ij->i", d1, d1), np.einsum("ij,ij->i", d2, d2)
    b, c, f = np.einsum("ij,ij->i", d1, d2), np.einsum("ij,ij->i", d1, r), np.einsum("ij,ij->i", d2, r)
    den = a * e - b * b
    s = np.where(den > 1e-18, np.clip((b * f - c * e) / np.where(den > 1e-18, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(a0 + s[:, None] * d1 - b0 - t[:, None] * d2, axis=1)
