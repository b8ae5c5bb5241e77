"""Compiled modal damping by double diagonalization (used by the controller's tick and by
:class:`reflexarm.control.JointImpedanceController`)."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["modal_damping_into"]


@njit(cache=True)
def modal_damping_into(M, stiffness, damping_ratio, out):  # pragma: no cover - compiled
    """D = L U diag(2 xi sqrt(lambda)) U^T L^T with M = L L^T and L^-1 K L^-T = U diag(lambda) U^T.

    Reads the upper triangle of M. Returns False (``out`` untouched) if M is not finite or not positive
    definite; never raises. Hand-written factorization and triangular solves: 7x7 solves through a threaded
    BLAS can cost milliseconds under load.
    """
    n = M.shape[0]
    for i in range(n):
        for j in range(i, n):
            if not np.isfinite(M[i, j]):
                return False
    L = np.zeros((n, n))
    for j in range(n):
        s = M[j, j]
        for m in range(j):
            s -= L[j, m] * L[j, m]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = M[j, i]  # = M[i, j], upper triangle
            for m in range(j):
                s -= L[i, m] * L[j, m]
            L[i, j] = s / L[j, j]
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
    for i in range(n):
        for j in range(n):
            if not np.isfinite(A[i, j]):
                return False
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
    return True
