"""Compiled (numba) inner loop of :meth:`reflexarm.control.Controller.step`.

One fused pass over the joints replaces some twenty small numpy calls whose dispatch overhead would
otherwise dominate a 1 kHz control tick. The math is exactly that of :class:`MomentumObserver`
(eqs. (4)-(6)), eq. (2) and eq. (12); ``tests/test_control.py`` checks the two against each other.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# rows of the ``gains`` array
K_ROW, KO_ROW, KO_DET_ROW, THRESHOLD_ROW, COULOMB_ROW, VISCOUS_ROW = range(6)
# rows of the ``obs`` state array
INT_ROW, P0_ROW, R_ROW, INT_DET_ROW, P0_DET_ROW, R_DET_ROW = range(6)
# entries of the ``flags`` array
(
    DT,
    INV_BAND,
    KAPPA_F,
    KAPPA_EXT,
    EPS_WEIGHT,
    LIMIT,
    INTEGRATE,
    USE_DET,
    GRAVITY_MODE,
) = range(9)
N_FLAGS = 9

NONFINITE_INPUT = -1
NONFINITE_OUTPUT = -2


@njit(cache=True)
def controller_tick(q, dq, tau_m, wrench, q_d, dq_d, g, C, p, ff, J, D, gains, obs, flags, tau_out, over_out):  # noqa: D103
    n = q.shape[0]
    acc = 0.0
    for i in range(n):
        acc += q[i] + dq[i] + tau_m[i] + q_d[i] + dq_d[i] + ff[i] + g[i] + p[i]
    for k in range(6):
        acc += wrench[k]
    if not np.isfinite(acc):
        return NONFINITE_INPUT
    dt = flags[DT]
    inv_band = flags[INV_BAND]
    kappa_f = flags[KAPPA_F]
    kappa_ext = flags[KAPPA_EXT]
    eps_w = flags[EPS_WEIGHT]
    limit = flags[LIMIT]
    integrate = flags[INTEGRATE] != 0.0
    use_det = flags[USE_DET] != 0.0
    gravity_mode = flags[GRAVITY_MODE] != 0.0
    n_over = 0
    out_acc = 0.0
    for i in range(n):
        # gamma = g - C^T dq  (5);  C dq for (2)
        ct_dq = 0.0
        c_dq = 0.0
        for j in range(n):
            ct_dq += C[j, i] * dq[j]
            c_dq += C[i, j] * dq[j]
        # alpha = kappa_f tau_f - kappa_ext J^T F  (6)
        s = dq[i] * inv_band
        if s > 1.0:
            s = 1.0
        elif s < -1.0:
            s = -1.0
        tau_f = gains[COULOMB_ROW, i] * s + gains[VISCOUS_ROW, i] * dq[i]
        alpha = kappa_f * tau_f
        if kappa_ext != 0.0:
            jt_f = 0.0
            for k in range(6):
                jt_f += J[k, i] * wrench[k]
            alpha -= jt_f
        base = tau_m[i] - (g[i] - ct_dq) - alpha
        # momentum observer (4), explicit Euler
        if integrate:
            obs[INT_ROW, i] += dt * (base + obs[R_ROW, i])
            obs[R_ROW, i] = gains[KO_ROW, i] * (p[i] - obs[P0_ROW, i] - obs[INT_ROW, i])
            if use_det:
                obs[INT_DET_ROW, i] += dt * (base + obs[R_DET_ROW, i])
                obs[R_DET_ROW, i] = gains[KO_DET_ROW, i] * (p[i] - obs[P0_DET_ROW, i] - obs[INT_DET_ROW, i])
        r_det = obs[R_DET_ROW, i] if use_det else obs[R_ROW, i]
        # detection (12)
        if r_det > gains[THRESHOLD_ROW, i] or -r_det > gains[THRESHOLD_ROW, i]:
            over_out[i] = True
            n_over += 1
        else:
            over_out[i] = False
        # control law (2) or gravity compensation (13)
        if gravity_mode:
            tau = g[i]
        else:
            d_e = 0.0
            for j in range(n):
                d_e += D[i, j] * (dq_d[j] - dq[j])
            tau = gains[K_ROW, i] * (q_d[i] - q[i]) + d_e + g[i] + c_dq + ff[i] + kappa_f * tau_f
            if eps_w != 0.0:
                r = obs[R_ROW, i]
                if r > limit:
                    r = limit
                elif r < -limit:
                    r = -limit
                tau -= eps_w * r
        tau_out[i] = tau
        out_acc += tau
    if not np.isfinite(out_acc):
        return NONFINITE_OUTPUT
    return n_over


@njit(cache=True)
def modal_damping_into(M, stiffness, damping_ratio, out):  # noqa: D103
    # D = L U diag(2 xi sqrt(lambda)) U^T L^T with M = L L^T and L^-1 K L^-T = U diag(lambda) U^T.
    # Hand-written triangular solve: 7x7 solves through a threaded BLAS can cost milliseconds under load.
    n = M.shape[0]
    L = np.linalg.cholesky(M)
    B = np.zeros((n, n))  # B = L^-1 sqrt(K), lower triangular
    for j in range(n):
        B[j, j] = np.sqrt(stiffness[j]) / L[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for m in range(j, i):
                s += L[i, m] * B[m, j]
            B[i, j] = -s / L[i, i]
    A = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for m in range(j + 1):
                s += B[i, m] * B[j, m]
            A[i, j] = s
            A[j, i] = s
    lam, U = np.linalg.eigh(A)
    LU = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for m in range(i + 1):
                s += L[i, m] * U[m, j]
            LU[i, j] = s
    for j in range(n):
        lam[j] = 2.0 * damping_ratio[j] * np.sqrt(max(lam[j], 0.0))
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for m in range(n):
                s += LU[i, m] * lam[m] * LU[j, m]
            out[i, j] = s
            out[j, i] = s
    return out
