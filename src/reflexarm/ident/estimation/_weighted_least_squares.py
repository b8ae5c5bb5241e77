"""Row-chunked weighted least squares per joint (the solver behind eq. (18), see :class:`_GramAccumulator`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class _Solution:
    x: np.ndarray
    information: np.ndarray  # A^T W A
    covariance: np.ndarray  # (A^T W A)^+
    residual_norm: float
    condition_number: float  # of the column-equilibrated weighted regressor
    rank_deficiency: int


class _GramAccumulator:
    """Row-chunked weighted least squares per joint: keeps G_j = [A_j b_j]^T [A_j b_j], (p+1) x (p+1).

    Since Sigma is diagonal per joint, the weighted problem of any weights is ``sum_j G_j / sigma_j^2``,
    so one pass over the data serves the unweighted pass, the weighted solve and the residual
    statistics (``|A_j x - b_j|^2 = (x, -1)^T G_j (x, -1)``). The solve equilibrates the columns
    (unit diagonal, which removes the parameters' units from the conditioning) and uses the eigen-
    decomposition of the equilibrated information matrix: its relative accuracy is about eps * cond^2
    of the equilibrated regressor (1e-10 at the warning limit cond = 1e3), and a rank-deficient problem
    gets the minimum-norm solution instead of a failure. (A chunked QR would be accurate to eps * cond
    but costs 10-100x more on a shared machine, where multi-threaded LAPACK QR of tall matrices degrades
    badly.)
    """

    def __init__(self, n: int, p: int) -> None:
        self.n = n
        self.p = p
        self.G = np.zeros((n, p + 1, p + 1))
        self.rows = np.zeros(n, dtype=np.int64)

    def add(self, M: np.ndarray, keep: np.ndarray | None = None) -> None:
        """M: (n, m, p + 1) rows [A_j b_j] per joint; keep: (m, n) bool, rows to use (default all)."""
        for j in range(self.n):
            Mj = M[j] if keep is None else M[j][keep[:, j]]
            self.G[j] += Mj.T @ Mj
            self.rows[j] += Mj.shape[0]

    def solve(self, weights: np.ndarray) -> _Solution:
        """min sum_j w_j^2 |A_j x - b_j|^2 (minimum-norm in equilibrated coordinates if rank deficient)."""
        p = self.p
        G = np.einsum("j,jab->ab", weights**2, self.G)
        AtA, Atb, btb = G[:p, :p], G[:p, p], G[p, p]
        d = np.sqrt(np.maximum(np.diag(AtA), 0.0))
        zero = d <= max(d.max(), 1e-300) * 1e-13
        ds = np.where(zero, 1.0, d)
        S = AtA / np.outer(ds, ds)
        S[zero, :] = 0.0
        S[:, zero] = 0.0
        ev, V = np.linalg.eigh(0.5 * (S + S.T))
        keep = ev > max(ev[-1], 1e-300) * 1e-12
        cond = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")
        # y = S^+ (A^T b / d): eigen-decomposition solve, exact pseudo-inverse when rank deficient
        rhs = np.where(zero, 0.0, Atb / ds)
        y = V[:, keep] @ ((V[:, keep].T @ rhs) / ev[keep])
        x = y / ds
        res2 = max(float(btb - 2 * x @ Atb + x @ AtA @ x), 0.0)
        # covariance factor of the estimate: (A^T W A)^+ in the original coordinates
        cov = (V[:, keep] / ev[keep]) @ V[:, keep].T / np.outer(ds, ds)
        return _Solution(x, AtA, cov, float(np.sqrt(res2)), cond, int(p - keep.sum()))

    def residual_ss(self, x: np.ndarray) -> np.ndarray:
        """sum over samples of (A_j x - b_j)^2 per joint."""
        y = np.r_[x, -1.0]
        return np.maximum(np.einsum("a,jab,b->j", y, self.G, y), 0.0)

    def transformed(self, T: np.ndarray) -> _GramAccumulator:
        """The accumulator of the rows ``[A_j b_j] T`` (T: (p + 1, p' + 1)), e.g. a column moved into b."""
        out = _GramAccumulator(self.n, T.shape[1] - 1)
        out.G = np.einsum("ai,jab,bk->jik", T, self.G, T)
        out.rows = self.rows.copy()
        return out
