"""Scalar measures of closed-loop runs: MSIE (20), steady-state windows, displacements, apparent stiffness."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from reflexarm.errors import DataError

__all__ = [
    "apparent_stiffness",
    "msie",
    "msie_per_joint",
    "normalize_by_max",
    "rms",
    "window_mean",
]


def _time_series(t: npt.ArrayLike, x: npt.ArrayLike, name: str) -> tuple[np.ndarray, np.ndarray]:
    tt = np.asarray(t, dtype=float).reshape(-1)
    xx = np.asarray(x, dtype=float)
    if xx.ndim == 1:
        xx = xx[:, None]
    if xx.shape[0] != tt.size:
        raise DataError(f"{name} has {xx.shape[0]} samples but t has {tt.size}")
    if tt.size < 2:
        raise DataError(f"{name} needs at least 2 samples; got {tt.size}")
    if not np.all(np.diff(tt) > 0):
        raise DataError("time must be strictly increasing")
    if not (np.all(np.isfinite(tt)) and np.all(np.isfinite(xx))):
        raise DataError(f"{name} contains NaN/inf")
    return tt, xx


def msie_per_joint(t: npt.ArrayLike, q: npt.ArrayLike, q_ref: npt.ArrayLike) -> np.ndarray:
    """Each joint's share of (20): ``1/T_f int_0^T_f (q_i - q_ref_i)^2 dt`` (n_j,) [rad^2]; MSIE is their mean.

    ``q`` and ``q_ref`` are sampled at the same times ``t`` (shape (N, n_j)); the integral is the
    trapezoidal rule over ``[t[0], t[-1]]`` and ``T_f = t[-1] - t[0]``.

    Raises:
        DataError: shapes differ, fewer than two samples, time not increasing, NaN/inf.
    """
    tt, qq = _time_series(t, q, "q")
    _, rr = _time_series(t, q_ref, "q_ref")
    if qq.shape != rr.shape:
        raise DataError(f"q and q_ref must have the same shape; got {qq.shape} and {rr.shape}")
    e2 = (qq - rr) ** 2
    return np.asarray(np.trapezoid(e2, tt, axis=0) / (tt[-1] - tt[0]))


def msie(t: npt.ArrayLike, q: npt.ArrayLike, q_ref: npt.ArrayLike) -> float:
    """Mean squared integrated error, eq. (20): ``1/(n_j T_f) sum_i int_0^T_f (q_i - q_ref_i)^2 dt`` [rad^2].

    See :func:`msie_per_joint` for the sampling and the errors raised.
    """
    return float(msie_per_joint(t, q, q_ref).mean())


def normalize_by_max(values: Sequence[float] | npt.ArrayLike) -> np.ndarray:
    """``||MSIE|| = MSIE / max(MSIE)`` over one figure (Figs. 13 and 14 are normalised separately)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise DataError("cannot normalise an empty set of values")
    m = float(np.nanmax(v))
    if not np.isfinite(m) or m <= 0.0:
        raise DataError(f"cannot normalise by a maximum of {m!r}")
    return v / m


def window_mean(t: npt.ArrayLike, x: npt.ArrayLike, t0: float, t1: float) -> np.ndarray:
    """Mean of ``x`` over the samples with ``t0 <= t < t1`` (e.g. a steady-state window)."""
    tt, xx = _time_series(t, x, "x")
    sel = (tt >= t0) & (tt < t1)
    if not np.any(sel):
        raise DataError(f"no samples in the window [{t0}, {t1}) s; the data span [{tt[0]}, {tt[-1]}] s")
    out = xx[sel].mean(axis=0)
    return out if np.asarray(x).ndim > 1 else out[0]


def rms(x: npt.ArrayLike) -> float:
    """Root mean square over all entries."""
    a = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(a * a)))


def apparent_stiffness(force: npt.ArrayLike, displacement: npt.ArrayLike) -> float:
    """Stiffness felt by whoever pushes [N/m]: ``|f| / (dx . f/|f|)``, the displacement along the force.

    Sideways motion of the pushed point (the arm's compliance need not be aligned with the push) does not
    count; this is the f_x over Delta x of Fig. 11.

    Raises:
        DataError: zero force, or no displacement along the force.
    """
    f = np.asarray(force, dtype=float)
    fn = float(np.linalg.norm(f))
    if fn == 0.0:
        raise DataError("zero force: the apparent stiffness is undefined")
    along = float(np.asarray(displacement, dtype=float) @ f) / fn
    if along <= 0.0:
        raise DataError(f"the point did not yield along the force (displacement along it {along:.3g} m)")
    return fn / along
