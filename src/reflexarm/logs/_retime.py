"""Re-timing of jittery host time stamps on the robot's own period (see :mod:`reflexarm.logs`)."""

from __future__ import annotations

import numpy as np

#: Re-timing is refused if it would move a sample by more than this many nominal periods.
MAX_RETIME_SHIFT = 6.0
#: A step counts as regular if it is within this fraction of a period of a whole number of periods.
_TICK_TOLERANCE = 0.2


def _step_durations(q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Duration of each step implied by the measured displacement and mean velocity [s] (NaN if at rest)."""
    v = 0.5 * (dq[1:] + dq[:-1])
    vv = np.sum(v * v, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(vv > 0, np.sum(v * (q[1:] - q[:-1]), axis=1) / vv, np.nan)


def _estimate_period(t: np.ndarray, q: np.ndarray, dq: np.ndarray) -> float:
    """The sample period: the median host step, or, when the host steps are irregular, the typical step
    duration implied by q and dq (the robot's own clock), adjusted so that a whole number of periods
    spans the log by the host clock (which is right on average)."""
    steps = np.diff(t)
    T = float(np.median(steps[steps > 0]))
    ticks = steps / T
    if not np.any(np.abs(ticks - np.maximum(np.round(ticks), 1.0)) > _TICK_TOLERANCE):
        return T
    d = _step_durations(q, dq)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size < 10:
        return T
    T_q = float(np.median(d))
    one = d[(d > 0.5 * T_q) & (d < 1.5 * T_q)]  # the single-tick cluster
    if one.size >= 10:
        T_q = float(np.median(one))
    total = (t[-1] - t[0]) / T_q
    return float((t[-1] - t[0]) / max(round(total), 1)) if total > 0 else T


def _retime(t: np.ndarray, q: np.ndarray, dq: np.ndarray, T: float, where: str) -> tuple[np.ndarray, str]:
    """Re-time samples on a grid of period T; see the module docstring."""
    steps = np.diff(t)
    v = 0.5 * (dq[1:] + dq[:-1])
    disp = q[1:] - q[:-1]
    est = _step_durations(q, dq) / T
    ok = np.isfinite(est) & (np.round(est) >= 1) & (np.abs(est - np.round(est)) < _TICK_TOLERANCE)
    new_t = _align_ticks(t, np.nan_to_num(est), ok, T)
    lo, hi = steps.min() * 1e3, steps.max() * 1e3

    def inconsistency(tt: np.ndarray) -> float:
        r = disp - v * np.diff(tt)[:, None]
        return float(np.sqrt(np.mean(r**2)) / max(np.sqrt(np.mean((v * T) ** 2)), 1e-300))

    if new_t is None:
        fixed = t.copy()
        for i in range(1, fixed.size):
            if fixed[i] <= fixed[i - 1]:
                fixed[i] = fixed[i - 1] + 1e-3 * T
        msg = (
            f"{where}: time steps are irregular ({lo:.3g} to {hi:.3g} ms around a {T * 1e3:.4g} ms period) and no "
            f"re-timing on the period grid stays within {MAX_RETIME_SHIFT:g} periods of the host clock; kept the host "
            "time stamps (made strictly increasing)"
        )
        return fixed, msg
    ticks = np.round(np.diff(new_t) / T).astype(np.int64)
    shift = np.abs(new_t - t)
    gaps = int(np.sum(ticks > 1))
    msg = (
        f"{where}: time stamps jitter ({lo:.3g} to {hi:.3g} ms steps around a {T * 1e3:.4g} ms period); re-timed "
        f"{t.size:,} samples on the {T * 1e3:.4g} ms grid, aligning the step counts implied by q and dq "
        f"({int(ok.sum()):,} of {steps.size:,} steps unambiguous) with the host clock; largest shift "
        f"{shift.max() * 1e3:.3g} ms; mismatch |delta q - dq dt| / |dq T| {inconsistency(t):.3f} -> "
        f"{inconsistency(new_t):.3f}; {gaps:,} gaps of 2 to {int(ticks.max())} periods remain (resample to fill them)"
    )
    return new_t, msg


def _align_ticks(t: np.ndarray, est: np.ndarray, ok: np.ndarray, T: float) -> np.ndarray | None:
    """Most likely tick index of each sample (Viterbi over offsets from the host-rounded index).

    Sample i sits on tick n_i = h_i + d_i, h_i = round((t_i - t_0) / T), |d_i| <= W. The cost of a path
    is sum_i ((T n_i - (t_i - t_0)) / T)^2 (host clock, jitter of about one period) plus, on steps where
    q/dq give an unambiguous duration ``est`` [periods], ((est - (n_i - n_{i-1})) / 0.1)^2; every step
    must advance by at least one tick. Returns None if no path exists within the window.
    """
    W = int(MAX_RETIME_SHIFT)
    d = np.arange(-W, W + 1)
    h = np.round((t - t[0]) / T).astype(np.int64)
    rel = (t - t[0]) / T
    cost = (h[0] + d - rel[0]) ** 2
    cost[d != 0] = np.inf  # the first sample defines the grid
    back = np.empty((t.size, d.size), dtype=np.int64)
    cols = np.arange(d.size)
    for i in range(1, t.size):
        k = (h[i] + d)[None, :] - (h[i - 1] + d)[:, None]
        edge = np.where(k < 1, np.inf, 0.0)
        if ok[i - 1]:
            edge = edge + ((est[i - 1] - k) / 0.1) ** 2
        total = cost[:, None] + edge
        back[i] = np.argmin(total, axis=0)
        cost = total[back[i], cols] + (h[i] + d - rel[i]) ** 2
    if not np.isfinite(cost.min()):
        return None
    path = np.empty(t.size, dtype=np.int64)
    path[-1] = int(np.argmin(cost))
    for i in range(t.size - 1, 0, -1):
        path[i - 1] = back[i][path[i]]
    return t[0] + T * (h + d[path]).astype(float)
