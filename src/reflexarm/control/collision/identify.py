"""Identification: the contact point on a link's surface and the contact force, from the joint residual.

Method: every candidate point p on the link's collision surface (``reflexarm.robots.collision_geometry``) is
scored by how well one contact force there explains the residual r (the observer's estimate of
``tau_ext = J_c^T f``)::

    f(p) = argmin_f |J_p^T f - r|   subject to f in the friction cone at p (f pushes into the surface),
    score(p) = |J_p^T f(p) - r|  [Nm],

and the best point wins. This is the deterministic, exhaustive form of the Contact Particle Filter
(L. Manuelli and R. Tedrake, "Localizing external contact using proprioceptive sensors: The Contact
Particle Filter", IROS 2016), which scores surface particles by the same constrained least-squares fit
under a linearised friction cone. Here every surface point is scored at every call (no particles, no
resampling, no motion model), so the result is a pure function of (q, r).

reflexarm does NOT use the line-of-action method of S. Vorndamme, M. Schappler, S. Haddadin, "Collision
detection, isolation and identification for humanoids", ICRA 2017 (wrench at the link from the
pseudo-inverse, the force's line of action intersected with the link geometry), whose code release names
the patent DE 10 2017 005 080.5 and the US application US 2020/0061835.

The friction cone (coefficient ``friction_coefficient``, 0.5 as in the Contact Particle Filter's open
implementations) is the pyramid of ``cone_edges`` unit generators ``d_k = -n + mu (cos a_k t1 + sin a_k t2)``
inscribed in the circular cone around the inward normal -n. The constrained fit is solved exactly: the
optimum lies in the interior (the unconstrained 3x3 solve, if its solution is inside the pyramid), on a
facet (a 2x2 solve on two adjacent generators, both weights >= 0), on an edge (a scalar) or at the apex
(f = 0); the candidate with the largest reduction of ``|r|^2`` among the feasible ones is the optimum.
Singular facets and interiors are skipped (their optimum is then attained on an edge). With
``A = J_p J_p^T`` and ``b = J_p r`` everything is a fixed number of 3x3 and 2x2 solves per point, and
``J_p = J_v - [p - o]_x J_w`` comes from the link's frame Jacobian computed once per call: a fixed
candidate set, no allocation per call in the C++ port (``reflexarm::ContactIsolator``).

What a residual determines on link i (a fixed-base arm, i 0-based): a force on link i moves only joints
0..i, so the link's 6 x (i+1) world Jacobian bounds what can be recovered. A point on a surface (2
coordinates) and a force (3) need about 5 independent residual components: with rank >= 5 point and force
are determined (``POINT_AND_FORCE``). Below that, the consistent points form a set: if the forces along it
agree (within :data:`FORCE_AGREEMENT` and :data:`DIRECTION_AGREEMENT_DEG`) the force is reported alone
(``FORCE_ONLY``: "point undetermined"), otherwise only the link (``LINK_ONLY``: "point undetermined, force
undetermined"). A force needs rank(J_p) = 3 at the point. A link without collision geometry gives the link
and "point unknown".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from reflexarm.control.collision.contact import ContactEstimate, Determined
from reflexarm.errors import ConfigError
from reflexarm.robots.collision_geometry import CollisionGeometry
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DIRECTION_AGREEMENT_DEG",
    "FORCE_AGREEMENT",
    "ContactIdentifier",
    "LinkFit",
    "LinkKinematics",
    "compute_link_kinematics",
]

#: Relative magnitude and direction [deg] within which the forces along a consistent set "agree" (FORCE_ONLY).
FORCE_AGREEMENT = 0.10
DIRECTION_AGREEMENT_DEG = 10.0
#: Singular values below this fraction of the largest count as zero in the rank tests.
RANK_TOLERANCE = 1e-6
#: The interior (3x3) solve is skipped when det(A) <= INTERIOR_CONDITION * (trace(A)/3)^3.
INTERIOR_CONDITION = 1e-9
#: A facet (2x2) solve is skipped when det(G) <= FACET_CONDITION * G_00 * G_11 (parallel edge torques).
FACET_CONDITION = 1e-10
#: An edge whose torque |J_p^T d|^2 is below EDGE_FLOOR * max trace(A) moves no joint (treated as the apex).
EDGE_FLOOR = 1e-14


@dataclass(frozen=True)
class LinkKinematics:
    """Joint frames and Jacobians at one configuration, computed once per call.

    Attributes:
        q: (n,) the configuration.
        rotations: (n, 3, 3) world orientation of each joint frame.
        origins: (n, 3) world position of each joint frame origin [m].
        jacobians: (n, 6, n) world-aligned Jacobian of each joint frame at its origin (linear; angular).
    """

    q: np.ndarray
    rotations: np.ndarray
    origins: np.ndarray
    jacobians: np.ndarray


def compute_link_kinematics(robot: RobotModel, q: np.ndarray, data: pin.Data | None = None) -> LinkKinematics:
    """Joint placements and LOCAL_WORLD_ALIGNED joint Jacobians of every joint at ``q`` (one Pinocchio pass)."""
    model = robot.pin_model
    d = model.createData() if data is None else data
    pin.computeJointJacobians(model, d, q)
    n = robot.n
    rotations = np.empty((n, 3, 3))
    origins = np.empty((n, 3))
    jacobians = np.empty((n, 6, n))
    for i in range(n):
        rotations[i] = d.oMi[i + 1].rotation
        origins[i] = d.oMi[i + 1].translation
        jacobians[i] = pin.getJointJacobian(model, d, i + 1, pin.LOCAL_WORLD_ALIGNED)
    return LinkKinematics(np.array(q, dtype=float), rotations, origins, jacobians)


@dataclass(frozen=True)
class LinkFit:
    """Every candidate point of one link scored against a residual.

    Attributes:
        link: 0-based joint index.
        points: (m, 3) candidate points, world [m].
        normals: (m, 3) outward normals, world.
        forces: (m, 3) best force at each point (in its friction cone), world [N].
        errors: (m,) fit error ``|W (J_p^T f - r)|`` at each point (weighted; [Nm] without weights).
        best: index of the best point (-1 when the link has no geometry).
        link_rank: rank of the link's 6 x (link+1) Jacobian (independent residual components).
        wrench_error: error of the best unconstrained wrench at the link origin [Nm] (a lower bound of
            ``errors``; the only score of a link without geometry).
        jacobian: (6, n) the link's world-aligned Jacobian at its origin.
        origin: (3,) the link's joint frame origin, world [m].
    """

    link: int
    points: np.ndarray
    normals: np.ndarray
    forces: np.ndarray
    errors: np.ndarray
    best: int
    link_rank: int
    wrench_error: float
    jacobian: np.ndarray
    origin: np.ndarray

    @property
    def best_error(self) -> float:
        """The best point's fit error, or the wrench error for a link without geometry [Nm]."""
        return float(self.errors[self.best]) if self.best >= 0 else self.wrench_error


def _tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents per normal (a fixed rule, reproduced in C++)."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


class ContactIdentifier:
    """Scores the candidate points of each link against a residual (see the module docstring).

    Args:
        robot: the controller's model (its kinematics are used).
        geometry: the links' collision surfaces (:func:`~reflexarm.robots.collision_geometry.link_collision_geometry`).
        friction_coefficient: mu of the friction cone, >= 0 (0.5 as in the Contact Particle Filter).
        cone_edges: generators of the friction pyramid, >= 3.

    Raises:
        ConfigError: geometry of another arm, bad friction coefficient or edge count.
    """

    def __init__(
        self,
        robot: RobotModel,
        geometry: CollisionGeometry,
        *,
        friction_coefficient: float = 0.5,
        cone_edges: int = 8,
    ) -> None:
        if geometry.n != robot.n:
            raise ConfigError(f"collision geometry has {geometry.n} links; robot {robot.name!r} has {robot.n} joints")
        mu = float(friction_coefficient)
        if not np.isfinite(mu) or mu < 0.0:
            raise ConfigError(f"friction_coefficient must be a finite number >= 0; got {friction_coefficient!r}")
        if isinstance(cone_edges, bool) or not isinstance(cone_edges, (int, np.integer)) or cone_edges < 3:
            raise ConfigError(f"cone_edges must be an integer >= 3; got {cone_edges!r}")
        self.robot = robot
        self.geometry = geometry
        self.friction_coefficient = mu
        self.cone_edges = int(cone_edges)
        self._data = robot.pin_model.createData()
        angles = 2.0 * np.pi * np.arange(self.cone_edges) / self.cone_edges
        self._generators: list[np.ndarray] = []
        self._facet_normals: list[np.ndarray] = []
        for surface in geometry.links:
            n_out = surface.normals
            t1, t2 = _tangent_basis(n_out) if surface.size else (n_out, n_out)
            D = -n_out[:, None, :] + mu * (
                np.cos(angles)[None, :, None] * t1[:, None, :] + np.sin(angles)[None, :, None] * t2[:, None, :]
            )
            D /= np.linalg.norm(D, axis=2, keepdims=True)
            C = np.cross(D, np.roll(D, -1, axis=1))  # normal of the facet spanned by edges k, k+1
            C *= np.sign(np.einsum("mki,mi->mk", C, -n_out))[:, :, None]  # oriented into the pyramid
            self._generators.append(D)
            self._facet_normals.append(C)

    def kinematics(self, q: np.ndarray) -> LinkKinematics:
        """Joint frames and Jacobians at ``q`` (checked by the caller)."""
        return compute_link_kinematics(self.robot, q, self._data)

    def fit_link(
        self, kin: LinkKinematics, link: int, residual: np.ndarray, weights: np.ndarray | None = None
    ) -> LinkFit:
        """Score every candidate point of ``link`` against ``residual`` (vectorised over the points).

        ``weights`` (n,), positive: the fit minimises ``|W (J_p^T f - r)|`` with ``W = diag(weights)`` (the
        inverse noise level per joint, as the Contact Particle Filter weights by the noise covariance);
        ``errors`` and ``wrench_error`` are in that norm. Default: unweighted.
        """
        w = np.ones(residual.shape[0]) if weights is None else weights
        surface = self.geometry.links[link]
        R, o, J = kin.rotations[link], kin.origins[link], kin.jacobians[link]
        r = w * residual
        link_rank = _rank(J[:, : link + 1])
        wrench_error = _wrench_error(J * w[None, :], r)
        if not surface.has_geometry:
            empty = np.zeros((0, 3))
            return LinkFit(link, empty, empty, empty, np.zeros(0), -1, link_rank, wrench_error, J, o)
        d = surface.points @ R.T  # p - o
        points = d + o
        normals = surface.normals @ R.T
        JpT = J[:3].T[None, :, :] + np.cross(J[3:].T[None, :, :], d[:, None, :])  # (m, n, 3): J_p^T
        JpT *= w[None, :, None]
        forces = self._constrained_forces(JpT, r, self._generators[link] @ R.T, self._facet_normals[link] @ R.T)
        errors = np.linalg.norm(np.einsum("mci,mi->mc", JpT, forces) - r, axis=1)
        best = int(np.argmin(errors))
        return LinkFit(link, points, normals, forces, errors, best, link_rank, wrench_error, J, o)

    def _constrained_forces(self, JpT: np.ndarray, r: np.ndarray, D: np.ndarray, C: np.ndarray) -> np.ndarray:
        """argmin |J_p^T f - r| over the friction pyramid, per point: interior, facets, edges, apex."""
        m, K = D.shape[0], D.shape[1]
        A = np.einsum("mci,mcj->mij", JpT, JpT)
        b = np.einsum("mci,c->mi", JpT, r)
        G = np.einsum("mki,mij,mlj->mkl", D, A, D)
        h = np.einsum("mki,mi->mk", D, b)
        # edges: f = t d_k, t >= 0
        gg = np.einsum("mkk->mk", G)
        floor = EDGE_FLOOR * max(float(np.einsum("mii->m", A).max()), np.finfo(float).tiny)
        live = gg > floor
        t = np.where(live, np.maximum(h, 0.0) / np.where(live, gg, 1.0), 0.0)
        red_edge = t * h
        # facets: f = x1 d_k + x2 d_k+1, x >= 0
        h2, g2 = np.roll(h, -1, axis=1), np.roll(gg, -1, axis=1)
        g12 = np.einsum("mkk->mk", np.roll(G, -1, axis=2))  # G[k, k+1]
        det = gg * g2 - g12 * g12
        ok = live & np.roll(live, -1, axis=1) & (det > FACET_CONDITION * gg * g2)
        safe = np.where(ok, det, 1.0)
        x1 = (g2 * h - g12 * h2) / safe
        x2 = (gg * h2 - g12 * h) / safe
        ok &= (x1 >= 0.0) & (x2 >= 0.0)
        red_facet = np.where(ok, x1 * h + x2 * h2, -np.inf)
        # interior: the unconstrained solve, if inside the pyramid
        adj = _adjugate(A)
        detA = np.einsum("mi,mi->m", A[:, 0], adj[:, :, 0])
        tr = np.einsum("mii->m", A)
        well = detA > INTERIOR_CONDITION * (tr / 3.0) ** 3
        f_int = np.einsum("mij,mj->mi", adj, b) / np.where(well, detA, 1.0)[:, None]
        inside = np.all(np.einsum("mki,mi->mk", C, f_int) >= 0.0, axis=1)
        red_int = np.where(well & inside, np.einsum("mi,mi->m", f_int, b), -np.inf)
        # the best feasible candidate (apex: reduction 0)
        red = np.concatenate([red_int[:, None], red_facet, red_edge, np.zeros((m, 1))], axis=1)
        choice = np.argmax(red, axis=1)
        forces = np.zeros((m, 3))
        rows = np.arange(m)
        sel = choice == 0
        forces[sel] = f_int[sel]
        sel = (choice >= 1) & (choice <= K)
        k = choice[sel] - 1
        k2 = (k + 1) % K
        idx = rows[sel]
        forces[sel] = x1[idx, k][:, None] * D[idx, k] + x2[idx, k][:, None] * D[idx, k2]
        sel = (choice > K) & (choice <= 2 * K)
        k = choice[sel] - 1 - K
        idx = rows[sel]
        forces[sel] = t[idx, k][:, None] * D[idx, k]
        return forces

    # ------------------------------------------------------------------ the estimate on one link
    def estimate(
        self, fit: LinkFit, residual: np.ndarray, tolerance: float, *, candidate_links: tuple[int, ...] = ()
    ) -> ContactEstimate:
        """The contact estimate on ``fit``'s link and what the residual determines (see the module docstring).

        ``tolerance``: points whose fit error (as in ``fit.errors``) is within it of the best form the consistent
        set. The record's ``fit_error`` is the unweighted ``|J_c^T f - r|`` [Nm].
        """
        surface = self.geometry.links[fit.link]
        if fit.best < 0:
            return ContactEstimate(
                fit.link,
                surface.link_name,
                None,
                None,
                fit.wrench_error,
                Determined.LINK_ONLY,
                f"point unknown: link {surface.link_name!r} (joint {surface.joint_name!r}) has no collision "
                "geometry; force undetermined",
                candidate_links,
            )
        best = fit.best
        d = fit.points[best] - fit.origin
        error = float(
            np.linalg.norm((fit.jacobian[:3] + np.cross(fit.jacobian[3:].T, d).T).T @ fit.forces[best] - residual)
        )
        consistent = fit.errors <= fit.errors[best] + tolerance
        count = int(consistent.sum())
        spread = float(np.linalg.norm(fit.points[consistent] - fit.points[best], axis=1).max())

        def make(determined: Determined, reason: str, point: bool, force: bool) -> ContactEstimate:
            return ContactEstimate(
                fit.link,
                surface.link_name,
                fit.points[best].copy() if point else None,
                fit.forces[best].copy() if force else None,
                error,
                determined,
                reason,
                candidate_links,
                count,
                spread,
            )

        force_rank = _rank_sym(_point_gram(fit, best))
        rank_text = f"the link's Jacobian has rank {fit.link_rank} (5 needed for point and force)"
        if force_rank < 3:
            return make(
                Determined.LINK_ONLY,
                f"point undetermined, force undetermined: J_c^T has rank {force_rank} at the best point (3 needed "
                f"for the force); {rank_text}",
                False,
                False,
            )
        if fit.link_rank >= 5:
            return make(
                Determined.POINT_AND_FORCE,
                f"{rank_text}; {count} candidate point(s) within {tolerance:.3g} Nm of the best fit, up to "
                f"{spread * 100:.1f} cm from it",
                True,
                True,
            )
        F = fit.forces[consistent]
        mag = np.linalg.norm(F, axis=1)
        ref = float(np.linalg.norm(fit.forces[best]))
        tiny = np.finfo(float).tiny
        angle = float(np.degrees(np.arccos(np.clip((F @ fit.forces[best] / np.maximum(mag * ref, tiny)).min(), -1, 1))))
        rel = float(np.abs(mag - ref).max() / max(ref, tiny))
        along = (
            f"over the {count} consistent point(s) (up to {spread * 100:.1f} cm apart) the force varies by "
            f"{rel * 100:.1f} % and {angle:.1f} deg"
        )
        if rel <= FORCE_AGREEMENT and angle <= DIRECTION_AGREEMENT_DEG:
            return make(Determined.FORCE_ONLY, f"point undetermined: {rank_text}; {along}", False, True)
        return make(Determined.LINK_ONLY, f"point undetermined, force undetermined: {rank_text}; {along}", False, False)


def _point_gram(fit: LinkFit, index: int) -> np.ndarray:
    """A = J_p J_p^T at one candidate point (3, 3)."""
    J = fit.jacobian
    d = fit.points[index] - fit.origin
    Jp = J[:3] + np.cross(J[3:].T, d).T
    return Jp @ Jp.T


def _adjugate(A: np.ndarray) -> np.ndarray:
    """Adjugate of a batch of 3x3 matrices (A^-1 = adj(A) / det(A))."""
    adj = np.empty_like(A)
    adj[:, 0, 0] = A[:, 1, 1] * A[:, 2, 2] - A[:, 1, 2] * A[:, 2, 1]
    adj[:, 0, 1] = A[:, 0, 2] * A[:, 2, 1] - A[:, 0, 1] * A[:, 2, 2]
    adj[:, 0, 2] = A[:, 0, 1] * A[:, 1, 2] - A[:, 0, 2] * A[:, 1, 1]
    adj[:, 1, 0] = A[:, 1, 2] * A[:, 2, 0] - A[:, 1, 0] * A[:, 2, 2]
    adj[:, 1, 1] = A[:, 0, 0] * A[:, 2, 2] - A[:, 0, 2] * A[:, 2, 0]
    adj[:, 1, 2] = A[:, 0, 2] * A[:, 1, 0] - A[:, 0, 0] * A[:, 1, 2]
    adj[:, 2, 0] = A[:, 1, 0] * A[:, 2, 1] - A[:, 1, 1] * A[:, 2, 0]
    adj[:, 2, 1] = A[:, 0, 1] * A[:, 2, 0] - A[:, 0, 0] * A[:, 2, 1]
    adj[:, 2, 2] = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    return adj


def _rank(J: np.ndarray) -> int:
    s = np.linalg.svd(J, compute_uv=False)
    return int(np.sum(s > RANK_TOLERANCE * s[0])) if s.size and s[0] > 0.0 else 0


def _rank_sym(A: np.ndarray) -> int:
    """Rank of a symmetric PSD matrix J J^T: eigenvalues are squared singular values."""
    w = np.linalg.eigvalsh(A)
    top = float(w[-1])
    return int(np.sum(w > RANK_TOLERANCE**2 * top)) if top > 0.0 else 0


def _wrench_error(J: np.ndarray, r: np.ndarray) -> float:
    """|r - J^T w*| for the best wrench w* at the link origin (least squares)."""
    w, *_ = np.linalg.lstsq(J.T, r, rcond=None)
    return float(np.linalg.norm(J.T @ w - r))
