"""Re-timing of jittery host time stamps onto the robot's sample grid, only where that is safe.

The period T of a log is its median step. Its stamps are irregular when a step lies more than
:data:`_TICK_TOLERANCE` T from a whole number of periods. Such stamps are either host stamps that jitter
around the robot's regular ticks (a host clock reading a 1 kHz robot) or the robot's own irregular sample
times (a controller that logs every 10, 12 or 14 ms); only the first may be moved. The grid is fitted to
the stamps themselves: each sample goes to its nearest tick of the line ``a + T_grid n`` fitted by least
squares over doubling blocks of samples (so a long log does not drift off a slightly wrong period), and
the re-timing is kept only if

1. every sample moves by at most half a period (nearest tick),
2. no two samples land on one tick (the jitter would then be more than half a period),
3. no gap is created from jitter: a re-timed step of k >= 2 periods needs a stamp step of at least
   k - 1/2 periods,
4. the grid's period is within :data:`_GRID_PERIOD_TOLERANCE` of the median step, and
5. positions and velocities agree no worse than with the stamps (``|delta q - dq dt| / |dq T|``, where
   the joints move).

Otherwise the log's own stamps are kept (irregular stamps are valid: :func:`~reflexarm.logs.preprocess_log`
resamples them), and stamps that repeat are spread evenly up to the next stamp.
"""

from __future__ import annotations

import numpy as np

#: A step counts as regular if it is within this fraction of a period of a whole number of periods.
_TICK_TOLERANCE = 0.2
#: The fitted grid's period may differ from the median step by at most this fraction.
_GRID_PERIOD_TOLERANCE = 0.01
#: A re-timing whose q/dq mismatch exceeds the stamps' by this factor is refused.
_MISMATCH_TOLERANCE = 1.05


def irregular_steps(steps: np.ndarray, T: float) -> np.ndarray:
    """Steps that are not (close to) a whole number >= 1 of periods T, or do not advance."""
    ticks = steps / T
    return (np.abs(ticks - np.maximum(np.round(ticks), 1.0)) > _TICK_TOLERANCE) | (steps <= 0)


def _fit_grid(rel: np.ndarray, T0: float, fixed: bool) -> tuple[float, float, np.ndarray]:
    """(grid period, offset, tick of each sample): nearest ticks of a line fitted over doubling blocks."""
    T, a = T0, 0.0
    m = min(rel.size, 64)
    while True:
        n = np.round((rel[:m] - a) / T)
        if fixed or n[-1] == n[0]:
            a = float(np.mean(rel[:m] - T * n))
        else:
            T, a = (float(x) for x in np.polyfit(n, rel[:m], 1))
        if m == rel.size:
            break
        m = min(rel.size, 2 * m)
    return T, a, np.round((rel - a) / T).astype(np.int64)


def _mismatch(q: np.ndarray, dq: np.ndarray, t: np.ndarray, T: float) -> float | None:
    """RMS of ``delta q - dq_mean dt`` over RMS of ``dq_mean T`` (None when the joints do not move)."""
    v = 0.5 * (dq[1:] + dq[:-1])
    scale = float(np.sqrt(np.mean((v * T) ** 2)))
    if not scale > 0:
        return None
    r = (q[1:] - q[:-1]) - v * np.diff(t)[:, None]
    return float(np.sqrt(np.mean(r**2))) / scale


def _spread_repeats(t: np.ndarray) -> tuple[np.ndarray, int]:
    """Runs of equal stamps spread evenly up to the next stamp (one period after the last one at the end)."""
    out = t.copy()
    same = np.r_[False, np.diff(t) <= 0]
    if not same.any():
        return out, 0
    steps = np.diff(t)
    T = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1.0
    i = 0
    while i < t.size:
        j = i + 1
        while j < t.size and same[j]:
            j += 1
        if j - i > 1:
            end = t[j] if j < t.size else t[i] + T
            out[i:j] = t[i] + (end - t[i]) * np.arange(j - i) / (j - i)
        i = j
    return out, int(same.sum())


def retime(
    t: np.ndarray, q: np.ndarray, dq: np.ndarray, T: float, where: str, fixed: bool = False
) -> tuple[np.ndarray, str, bool]:
    """(times, message, True if the log was re-timed on the grid) for a log with irregular steps.

    ``T`` is the median step (or the period given, ``fixed``: then only the grid's offset is fitted).
    See the module docstring for when the grid is used and when the stamps are kept.
    """
    steps = np.diff(t)
    lo, hi = steps.min() * 1e3, steps.max() * 1e3
    rel = t - t[0]
    T_grid, a, n = _fit_grid(rel, T, fixed)
    new_t = t[0] + a + T_grid * n.astype(float)
    k = np.diff(n)

    def head(period: float) -> str:
        what = "the period given" if fixed else "the median step"
        return f"{where}: time steps irregular ({lo:.3g} to {hi:.3g} ms; period {period * 1e3:.4g} ms, {what})"

    why = None
    if np.any(k < 1):
        r = int(np.argmax(k < 1)) + 1
        why = f"put rows {r - 1} and {r} on one tick (the stamps jitter by more than half a period)"
    elif np.any(created := (k >= 2) & (steps < (k - 0.5) * T_grid)):
        r = int(np.argmax(created)) + 1
        why = (
            f"create {int(created.sum()):,} gap(s) from jitter (first: {int(k[r - 1])} periods before row {r}, "
            f"where the stamps step {steps[r - 1] * 1e3:.3g} ms)"
        )
    elif abs(T_grid / T - 1.0) > _GRID_PERIOD_TOLERANCE:
        why = f"need a grid period of {T_grid * 1e3:.4g} ms, not the median step (the stamps are no jittered grid)"
    before, after = _mismatch(q, dq, t, T), _mismatch(q, dq, new_t, T)
    if why is None and before is not None and after is not None and after > _MISMATCH_TOLERANCE * before:
        why = f"make positions and velocities agree worse (|delta q - dq dt| / |dq T| {before:.3f} -> {after:.3f})"
    if why is None:
        shift = np.abs(new_t - t)
        gaps = int(np.sum(k > 1))
        msg = (
            f"{head(T)}: host stamps jitter around the robot's ticks; re-timed {t.size:,} samples onto the "
            f"{T_grid * 1e3:.6g} ms grid fitted to them (nearest tick; largest shift {shift.max() * 1e3:.3g} ms, at "
            f"most half a period); "
            + (f"mismatch |delta q - dq dt| / |dq T| {before:.3f} -> {after:.3f}; " if before is not None else "")
            + (f"{gaps:,} gap(s) the stamps show remain (resampling fills them)" if gaps else "no gaps")
        )
        return new_t, msg, True
    kept, repeats = _spread_repeats(t)
    period = T if fixed else float(np.median(np.diff(kept)))
    msg = f"{head(period)}: kept the log's own time stamps: re-timing onto a grid would {why}" + (
        f"; {repeats:,} repeated stamp(s) spread evenly up to the next stamp (largest shift "
        f"{np.abs(kept - t).max() * 1e3:.3g} ms)"
        if repeats
        else ""
    )
    return kept, msg, bool(repeats)
