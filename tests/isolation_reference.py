"""A plain, slow reference of collision isolation and identification, written independently of the package.

- The point Jacobian J_p (3 x n) is taken by central finite differences of the point's world position
  (Pinocchio forward kinematics of the joint frame times the local point), not from J_v - [p - o]_x J_w.
- The friction-cone fit min |W (J_p^T f - r)| over f = D alpha, alpha >= 0 (the same pyramid of K edges
  around the inward normal) is solved point by point with scipy.optimize.nnls.
- Isolation: loop over the candidate links from the most distal significant joint, keep the most proximal
  link whose best fit is within the tolerance of the best of all.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.optimize import nnls

FD_STEP = 1e-6


def joint_placements(robot, q):
    data = robot.pin_model.createData()
    pin.forwardKinematics(robot.pin_model, data, q)
    return [data.oMi[i + 1].copy() for i in range(robot.n)]


def point_jacobian_fd(robot, q, link, local_point):
    """d p_world / dq (3, n) of a point fixed in joint frame ``link``, by central differences."""
    J = np.zeros((3, robot.n))
    for c in range(robot.n):
        e = np.zeros(robot.n)
        e[c] = FD_STEP
        plus = joint_placements(robot, q + e)[link].act(local_point)
        minus = joint_placements(robot, q - e)[link].act(local_point)
        J[:, c] = (plus - minus) / (2 * FD_STEP)
    return J


def pyramid(normal, mu, edges):
    """Unit edges (K, 3) of the friction pyramid about -normal, with the package's tangent rule (applied to the
    normal in the joint frame, so the pyramid turns with the link)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(normal, helper)
    t1 = t1 / np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    out = []
    for k in range(edges):
        a = 2 * np.pi * k / edges
        d = -normal + mu * (np.cos(a) * t1 + np.sin(a) * t2)
        out.append(d / np.linalg.norm(d))
    return np.array(out)


def fit_point(Jp, D, residual, weights):
    """(weighted error, force) of the best force f = D^T alpha, alpha >= 0, at one point."""
    B = (weights[:, None] * Jp.T) @ D.T  # n x K
    alpha, err = nnls(B, weights * residual)
    return err, D.T @ alpha


def fit_link(robot, geometry, q, link, residual, weights=None, mu=0.5, edges=8):
    """Errors (m,) and forces (m, 3) of every candidate point of ``link``, point by point."""
    w = np.ones(robot.n) if weights is None else weights
    surface = geometry.links[link]
    oMi = joint_placements(robot, q)[link]
    errors, forces = [], []
    for p_local, n_local in zip(surface.points, surface.normals, strict=True):
        Jp = point_jacobian_fd(robot, q, link, p_local)
        D = pyramid(n_local, mu, edges) @ oMi.rotation.T  # edges built in the joint frame, then rotated
        err, f = fit_point(Jp, D, residual, w)
        errors.append(err)
        forces.append(f)
    return np.array(errors), np.array(forces).reshape(-1, 3)


def isolate_link(robot, geometry, q, residual, significance, tolerance, weights=None):
    """The isolated link (or -1): most proximal candidate whose best fit is within ``tolerance`` of the best."""
    significant = np.flatnonzero(np.abs(residual) > significance)
    if significant.size == 0:
        return -1
    best = {}
    for link in range(int(significant[-1]), robot.n):
        if geometry.links[link].size == 0:
            w = np.ones(robot.n) if weights is None else weights
            data = robot.pin_model.createData()
            pin.computeJointJacobians(robot.pin_model, data, q)
            Jl = pin.getJointJacobian(robot.pin_model, data, link + 1, pin.LOCAL_WORLD_ALIGNED)
            x, *_ = np.linalg.lstsq((w[:, None] * Jl.T), w * residual, rcond=None)
            best[link] = float(np.linalg.norm(w[:, None] * Jl.T @ x - w * residual))
        else:
            best[link] = float(fit_link(robot, geometry, q, link, residual, weights)[0].min())
    top = min(best.values())
    return next(link for link in sorted(best) if best[link] <= top + tolerance)
