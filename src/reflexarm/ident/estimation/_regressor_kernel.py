"""Compiled per-sample Newton-Euler regressor (numba), called by :class:`reflexarm.ident.BatchRegressor`.

The math is the one documented in :mod:`reflexarm.ident.estimation.regressor`; numba turns the per-sample loop
over fixed-size 3-vectors into machine code (about 20x faster than a numpy formulation over the batch,
whose tiny batched 3x3 products are dominated by per-call overhead).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, fastmath=False, nogil=True)
def _cross(a0, a1, a2, b0, b1, b2):  # type: ignore[no-untyped-def]
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@nb.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _joint_transform(P, p, u0, u1, u2, qk, revolute, R):  # type: ignore[no-untyped-def]
    """R (filled) and p of a joint in its parent frame: R = R0 Rot(u, q), p = p0 (revolute); R = R0,
    p = p0 + R0 u q (prismatic); ``P``, ``p`` the joint's placement (R0, p0)."""
    if revolute:
        c = np.cos(qk)
        s = np.sin(qk)
        t = 1.0 - c
        r00 = c + t * u0 * u0
        r01 = t * u0 * u1 - s * u2
        r02 = t * u0 * u2 + s * u1
        r10 = t * u0 * u1 + s * u2
        r11 = c + t * u1 * u1
        r12 = t * u1 * u2 - s * u0
        r20 = t * u0 * u2 - s * u1
        r21 = t * u1 * u2 + s * u0
        r22 = c + t * u2 * u2
        for i in range(3):
            x0, x1, x2 = P[i, 0], P[i, 1], P[i, 2]
            R[i, 0] = x0 * r00 + x1 * r10 + x2 * r20
            R[i, 1] = x0 * r01 + x1 * r11 + x2 * r21
            R[i, 2] = x0 * r02 + x1 * r12 + x2 * r22
        return p[0], p[1], p[2]
    for i in range(3):
        for j in range(3):
            R[i, j] = P[i, j]
    return (
        p[0] + (R[0, 0] * u0 + R[0, 1] * u1 + R[0, 2] * u2) * qk,
        p[1] + (R[1, 0] * u0 + R[1, 1] * u1 + R[1, 2] * u2) * qk,
        p[2] + (R[2, 0] * u0 + R[2, 1] * u1 + R[2, 2] * u2) * qk,
    )


@nb.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _body_regressor(w0, w1, w2, l0, l1, l2, e0, e1, e2, B):  # type: ignore[no-untyped-def]
    """B (6, 10), the body's regressor in its own frame from its angular velocity w, angular acceleration l
    and the classical acceleration e of its origin: f = m e + (S(l) + S(w)^2) h ; n = -S(e) h + (L(l) +
    S(w) L(w)) I."""
    for i in range(6):
        for j in range(10):
            B[i, j] = 0.0
    B[0, 0], B[1, 0], B[2, 0] = e0, e1, e2
    # S(al) + S(w) S(w) = S(al) + w w^T - |w|^2 I
    ww = w0 * w0 + w1 * w1 + w2 * w2
    B[0, 1] = w0 * w0 - ww
    B[0, 2] = -l2 + w0 * w1
    B[0, 3] = l1 + w0 * w2
    B[1, 1] = l2 + w1 * w0
    B[1, 2] = w1 * w1 - ww
    B[1, 3] = -l0 + w1 * w2
    B[2, 1] = -l1 + w2 * w0
    B[2, 2] = l0 + w2 * w1
    B[2, 3] = w2 * w2 - ww
    # -S(e)
    B[3, 2], B[3, 3] = e2, -e1
    B[4, 1], B[4, 3] = -e2, e0
    B[5, 1], B[5, 2] = e1, -e0
    # L(al) + S(w) L(w), columns (Ixx, Ixy, Iyy, Ixz, Iyz, Izz)
    # L(w) = [[w0, w1, 0, w2, 0, 0], [0, w0, w1, 0, w2, 0], [0, 0, 0, w0, w1, w2]]
    # rows of S(w): [0, -w2, w1], [w2, 0, -w0], [-w1, w0, 0]
    # column Ixx: L(.)[:,0] = (x0, 0, 0)
    B[3, 4] = l0
    B[4, 4] = w2 * w0
    B[5, 4] = -w1 * w0
    # column Ixy: (x1, x0, 0)
    B[3, 5] = l1 - w2 * w0
    B[4, 5] = l0 + w2 * w1
    B[5, 5] = -w1 * w1 + w0 * w0
    # column Iyy: (0, x1, 0)
    B[3, 6] = -w2 * w1
    B[4, 6] = l1
    B[5, 6] = w0 * w1
    # column Ixz: (x2, 0, x0)
    B[3, 7] = l2 + w1 * w0
    B[4, 7] = w2 * w2 - w0 * w0
    B[5, 7] = l0 - w1 * w2
    # column Iyz: (0, x2, x1)
    B[3, 8] = -w2 * w2 + w1 * w1
    B[4, 8] = l2 - w0 * w1
    B[5, 8] = l1 + w0 * w2
    # column Izz: (0, 0, x2)
    B[3, 9] = w1 * w2
    B[4, 9] = -w0 * w2
    B[5, 9] = l2


@nb.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _to_world(Rw, ow, B, F):  # type: ignore[no-untyped-def]
    """F (6, 10): the body regressor B in world coordinates about the world origin (f_w = Rw f, n_w = Rw n
    + o x f_w), ``Rw``, ``ow`` the body frame's world pose."""
    for j in range(10):
        f0 = Rw[0, 0] * B[0, j] + Rw[0, 1] * B[1, j] + Rw[0, 2] * B[2, j]
        f1 = Rw[1, 0] * B[0, j] + Rw[1, 1] * B[1, j] + Rw[1, 2] * B[2, j]
        f2 = Rw[2, 0] * B[0, j] + Rw[2, 1] * B[1, j] + Rw[2, 2] * B[2, j]
        c0, c1, c2 = _cross(ow[0], ow[1], ow[2], f0, f1, f2)
        F[0, j], F[1, j], F[2, j] = f0, f1, f2
        F[3, j] = Rw[0, 0] * B[3, j] + Rw[0, 1] * B[4, j] + Rw[0, 2] * B[5, j] + c0
        F[4, j] = Rw[1, 0] * B[3, j] + Rw[1, 1] * B[4, j] + Rw[1, 2] * B[5, j] + c1
        F[5, j] = Rw[2, 0] * B[3, j] + Rw[2, 1] * B[4, j] + Rw[2, 2] * B[5, j] + c2


@nb.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _compose(Rw, ow, R, p0, p1, p2, Rnew):  # type: ignore[no-untyped-def]
    """(Rw, ow) <- (Rw R, ow + Rw p): the world pose of the child frame (``Rnew`` scratch)."""
    for i in range(3):
        ow[i] += Rw[i, 0] * p0 + Rw[i, 1] * p1 + Rw[i, 2] * p2
    for i in range(3):
        for j in range(3):
            Rnew[i, j] = Rw[i, 0] * R[0, j] + Rw[i, 1] * R[1, j] + Rw[i, 2] * R[2, j]
    for i in range(3):
        for j in range(3):
            Rw[i, j] = Rnew[i, j]


@nb.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _joint_torques(S, F, Yk):  # type: ignore[no-untyped-def]
    """Yk (n, 10 n): tau_i = sum_{j >= i} S_i . F_j, the joints' regressor rows of one sample."""
    n = S.shape[0]
    for i in range(n):
        for jl in range(i, n):
            for c in range(10):
                acc = 0.0
                for r in range(6):
                    acc += S[i, r] * F[jl, r, c]
                Yk[i, 10 * jl + c] = acc


@nb.njit(cache=True, fastmath=False, nogil=True)
def regressor_kernel(  # the arrays: Q, DQ, DDQ (N, n); placement_R (n, 3, 3), placement_p (n, 3); axis (n, 3)
    Q: np.ndarray, DQ: np.ndarray, DDQ: np.ndarray, placement_R: np.ndarray, placement_p: np.ndarray,
    axis: np.ndarray, revolute: np.ndarray, gravity: np.ndarray, Y: np.ndarray,
) -> None:  # fmt: skip
    """Fill ``Y`` (N, n, 10 n) with the joint-torque regressor of each sample (zeroed by the caller)."""
    N, n = Q.shape
    Rw = np.empty((3, 3))
    Rnew = np.empty((3, 3))
    R = np.empty((3, 3))
    ow = np.empty(3)
    S = np.empty((n, 6))  # motion subspaces in world coordinates, about the world origin
    F = np.empty((n, 6, 10))  # body regressors in world coordinates, about the world origin
    B = np.empty((6, 10))
    for k in range(N):
        for i in range(3):
            ow[i] = 0.0
            for j in range(3):
                Rw[i, j] = 1.0 if i == j else 0.0
        v0 = v1 = v2 = w0 = w1 = w2 = 0.0
        a0, a1, a2 = -gravity[0], -gravity[1], -gravity[2]
        l0 = l1 = l2 = 0.0
        for jt in range(n):
            qk = Q[k, jt]
            u0, u1, u2 = axis[jt, 0], axis[jt, 1], axis[jt, 2]
            # joint transform in the parent frame: R = R0 Rot(u, q), p = p0 (revolute); R0, p0 + R0 u q (prismatic)
            p0, p1, p2 = _joint_transform(placement_R[jt], placement_p[jt], u0, u1, u2, qk, revolute[jt], R)
            _compose(Rw, ow, R, p0, p1, p2, Rnew)  # world pose of this joint frame
            # motion transform parent -> child: w_c = R^T w, v_c = R^T (v + w x p); same for (a, alpha)
            c0, c1, c2 = _cross(w0, w1, w2, p0, p1, p2)
            x0, x1, x2 = v0 + c0, v1 + c1, v2 + c2
            vc0 = R[0, 0] * x0 + R[1, 0] * x1 + R[2, 0] * x2
            vc1 = R[0, 1] * x0 + R[1, 1] * x1 + R[2, 1] * x2
            vc2 = R[0, 2] * x0 + R[1, 2] * x1 + R[2, 2] * x2
            wc0 = R[0, 0] * w0 + R[1, 0] * w1 + R[2, 0] * w2
            wc1 = R[0, 1] * w0 + R[1, 1] * w1 + R[2, 1] * w2
            wc2 = R[0, 2] * w0 + R[1, 2] * w1 + R[2, 2] * w2
            c0, c1, c2 = _cross(l0, l1, l2, p0, p1, p2)
            x0, x1, x2 = a0 + c0, a1 + c1, a2 + c2
            ac0 = R[0, 0] * x0 + R[1, 0] * x1 + R[2, 0] * x2
            ac1 = R[0, 1] * x0 + R[1, 1] * x1 + R[2, 1] * x2
            ac2 = R[0, 2] * x0 + R[1, 2] * x1 + R[2, 2] * x2
            lc0 = R[0, 0] * l0 + R[1, 0] * l1 + R[2, 0] * l2
            lc1 = R[0, 1] * l0 + R[1, 1] * l1 + R[2, 1] * l2
            lc2 = R[0, 2] * l0 + R[1, 2] * l1 + R[2, 2] * l2
            dqk = DQ[k, jt]
            ddqk = DDQ[k, jt]
            s0, s1, s2 = u0 * dqk, u1 * dqk, u2 * dqk
            uw0 = Rw[0, 0] * u0 + Rw[0, 1] * u1 + Rw[0, 2] * u2
            uw1 = Rw[1, 0] * u0 + Rw[1, 1] * u1 + Rw[1, 2] * u2
            uw2 = Rw[2, 0] * u0 + Rw[2, 1] * u1 + Rw[2, 2] * u2
            if revolute[jt]:
                w0, w1, w2 = wc0 + s0, wc1 + s1, wc2 + s2
                c0, c1, c2 = _cross(w0, w1, w2, s0, s1, s2)
                l0, l1, l2 = lc0 + ddqk * u0 + c0, lc1 + ddqk * u1 + c1, lc2 + ddqk * u2 + c2
                c0, c1, c2 = _cross(vc0, vc1, vc2, s0, s1, s2)
                a0, a1, a2 = ac0 + c0, ac1 + c1, ac2 + c2
                v0, v1, v2 = vc0, vc1, vc2
                c0, c1, c2 = _cross(ow[0], ow[1], ow[2], uw0, uw1, uw2)
                S[jt, 0], S[jt, 1], S[jt, 2] = c0, c1, c2
                S[jt, 3], S[jt, 4], S[jt, 5] = uw0, uw1, uw2
            else:
                c0, c1, c2 = _cross(wc0, wc1, wc2, s0, s1, s2)
                a0, a1, a2 = ac0 + ddqk * u0 + c0, ac1 + ddqk * u1 + c1, ac2 + ddqk * u2 + c2
                l0, l1, l2 = lc0, lc1, lc2
                v0, v1, v2 = vc0 + s0, vc1 + s1, vc2 + s2
                w0, w1, w2 = wc0, wc1, wc2
                S[jt, 0], S[jt, 1], S[jt, 2] = uw0, uw1, uw2
                S[jt, 3] = S[jt, 4] = S[jt, 5] = 0.0
            # body regressor (local): f = m a_cl + (S(al) + S(w)^2) h ; n = -S(a_cl) h + (L(al) + S(w) L(w)) I
            c0, c1, c2 = _cross(w0, w1, w2, v0, v1, v2)
            e0, e1, e2 = a0 + c0, a1 + c1, a2 + c2  # classical acceleration of the origin
            _body_regressor(w0, w1, w2, l0, l1, l2, e0, e1, e2, B)
            _to_world(Rw, ow, B, F[jt])  # f_w = Rw f, n_w = Rw n + o x f_w
        _joint_torques(S, F, Y[k])  # tau_i = sum_{j >= i} S_i . F_j
