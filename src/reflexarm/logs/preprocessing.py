"""preprocess_log: uniform grid per gap-free segment, zero-phase low-pass filter, ddq by differentiation.

See :mod:`reflexarm.logs` for the whole pipeline; :func:`preprocess_log` is re-exported there.
"""

from __future__ import annotations

import warnings

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.robot_log import LogRepairWarning, RobotLog

__all__ = ["DEFAULT_CUTOFF_HZ", "DEFAULT_FILTER_ORDER", "DEFAULT_MAX_GAP_PERIODS", "MAX_GRID_FACTOR", "preprocess_log"]

#: Default low-pass cutoff for q, dq, ddq and the identification torques [Hz]. Identification
#: trajectories have their content below a few Hz (the paper's Fourier trajectories, Gaz's 0.075 Hz x 5
#: harmonics); 10 Hz keeps it undistorted while removing most of the differentiation noise.
DEFAULT_CUTOFF_HZ = 10.0
#: Butterworth order of the zero-phase filter (applied forwards and backwards: effective order 8).
DEFAULT_FILTER_ORDER = 4

#: Gaps (steps between samples) up to this many periods of the log are filled by interpolation; a longer
#: gap splits the log into segments that are resampled and filtered separately (nothing is interpolated
#: or filtered across it). 25 periods (25 ms at 1 kHz) is a quarter period of the default 10 Hz cutoff:
#: the cubic Hermite fill with the measured velocities as slopes is accurate there for motions with
#: content of a few Hz (identification trajectories), and the real Panda log's longest gap (16 ms) stays
#: a fill.
DEFAULT_MAX_GAP_PERIODS = 25
#: The resampling grid may hold at most this many times the log's sample count; checked before any
#: allocation (a grid period far below the log's own invents data and can exhaust memory).
MAX_GRID_FACTOR = 100


def preprocess_log(
    log: RobotLog,
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    period: float | None = None,
    filter_torque: bool = True,
    max_gap: float | None = None,
) -> RobotLog:
    """Uniform grid, zero-phase low-pass filter, ddq by differentiation; segments split at long gaps.

    Args:
        log: a validated log (possibly with gaps).
        cutoff_hz: Butterworth cutoff for q, dq (and ddq, derived from the filtered dq) [Hz]; None: no
            filtering (ddq is then the central difference of the raw dq).
        order: Butterworth order (applied forwards and backwards by ``filtfilt``: zero phase).
        period: grid period [s] (default: the log's median step).
        filter_torque: filter the torques with the same filter (kept raw in ``tau_raw``).
        max_gap: longest gap filled by interpolation [s] (default :data:`DEFAULT_MAX_GAP_PERIODS` periods
            of the log). A longer gap splits the log: each segment gets its own grid, filter and
            derivative, and the result's time jumps over the gap. Segments shorter than the filter's
            edge length (two periods of the cutoff; 3 samples without a filter) are dropped, with a
            :class:`LogRepairWarning` and a note.

    Returns:
        A new log, uniform within each segment, with ``ddq`` filled (a ddq given in the log is kept,
        resampled).

    Raises:
        DataError: non-positive period or ``max_gap``, cutoff above Nyquist, a grid of more than
            :data:`MAX_GRID_FACTOR` times the log's samples, no segment long enough to filter.
    """
    from scipy.signal import butter

    where = log.source
    T = log.period if period is None else float(period)
    if not (np.isfinite(T) and T > 0):
        raise DataError(f"{where}: resampling period must be positive; got {period!r}")
    gap = DEFAULT_MAX_GAP_PERIODS * log.period if max_gap is None else float(max_gap)
    if not (np.isfinite(gap) and gap >= T):
        raise DataError(f"{where}: max_gap must be at least the grid period {T:.6g} s; got {max_gap!r}")
    fs = 1.0 / T
    filt: tuple[np.ndarray, np.ndarray, int] | None = None
    min_len = 3
    if cutoff_hz is not None:
        if not 0 < cutoff_hz < 0.5 * fs:
            raise DataError(
                f"{where}: filter cutoff {cutoff_hz!r} Hz must be between 0 and the Nyquist frequency {0.5 * fs:.4g} Hz"
            )
        b, a = butter(order, cutoff_hz / (0.5 * fs))
        # odd extension over two periods of the cutoff, so the edge transient of the filter dies out
        padlen = max(3 * max(len(a), len(b)), int(round(2 * fs / cutoff_hz)))
        filt = (b, a, padlen)
        min_len = padlen + 1
    resample = not (log.is_uniform and period is None)
    steps = np.diff(log.t)
    cuts = np.flatnonzero(steps > gap * (1 + 1e-9)) + 1
    edges = np.r_[0, cuts, len(log)]
    spans = [(int(i0), int(i1)) for i0, i1 in zip(edges[:-1], edges[1:], strict=True)]
    # grid sizes, checked before anything is allocated
    # With the log's own period, each segment's grid spans the segment exactly (its period is the span over
    # the nearest whole number of periods): a grid that stopped short of the last sample would leave the
    # samples after it outside the states (validation of a jittery log, --split). A period the caller gives
    # is kept as given.
    fit = resample and period is None
    sizes = [
        (
            (max(int(round((log.t[i1 - 1] - log.t[i0]) / T)), 1) + 1)
            if fit
            else (int(np.floor((log.t[i1 - 1] - log.t[i0]) / T + 1e-6)) + 1)
        )
        if resample
        else i1 - i0
        for i0, i1 in spans
    ]
    total = sum(sizes)
    if total > MAX_GRID_FACTOR * len(log):
        raise DataError(
            f"{where}: resampling {len(log):,} samples at a {T:.6g} s period would need a grid of {total:,} samples "
            f"(more than {MAX_GRID_FACTOR} x the log); use a period near the log's own {log.period:.6g} s"
        )
    notes: list[str] = []
    if cuts.size:
        longest = int(np.argmax(steps[cuts - 1]))
        notes.append(
            f"split at {cuts.size:,} gap(s) longer than {gap:.6g} s (longest {steps[cuts[longest] - 1]:.6g} s after "
            f"t = {log.t[cuts[longest] - 1]:.6g} s) into {len(spans):,} segments, each resampled and filtered "
            "separately: nothing is interpolated or filtered across a gap"
        )
    kept = [(span, k) for span, k in zip(spans, sizes, strict=True) if k >= min_len]
    if len(kept) < len(spans):
        dropped = [span for span, k in zip(spans, sizes, strict=True) if k < min_len]
        n_drop = sum(i1 - i0 for i0, i1 in dropped)
        msg = (
            f"{where}: dropped {len(dropped):,} segment(s) between long gaps ({n_drop:,} samples) shorter than "
            f"{min_len} grid samples, the filter's edge length: their q, dq, ddq would be filter transient"
        )
        if not kept:
            raise DataError(msg.replace("dropped", "every one of the", 1) + "; nothing is left to identify on")
        warnings.warn(msg, LogRepairWarning, stacklevel=2)
        notes.append(msg)
    parts = [
        _preprocess_segment(
            log.select(slice(i0, i1)),
            (log.t[i1 - 1] - log.t[i0]) / (k - 1) if fit else T,
            k,
            resample,
            filt,
            filter_torque,
        )
        for (i0, i1), k in kept
    ]
    if resample:
        n_in = sum(i1 - i0 for (i0, i1), _ in kept)
        filled = sum(p[-1] for p in parts)
        periods = [(log.t[i1 - 1] - log.t[i0]) / (k - 1) for (i0, i1), k in kept] if fit else [T]
        notes.append(
            f"resampled {n_in:,} samples to a uniform {T * 1e3:.4g} ms grid of {sum(k for _, k in kept):,} samples "
            + (
                f"(each segment's grid spans it from its first to its last sample: period {min(periods) * 1e3:.6g}"
                f"..{max(periods) * 1e3:.6g} ms) "
                if fit
                else ""
            )
            + "(q cubic Hermite with dq as slopes, dq cubic spline, other signals linear; "
            + f"{filled:,} grid points filled)"
        )
    if cutoff_hz is not None:
        notes.append(
            f"zero-phase Butterworth low-pass (order {order}, forwards and backwards) at {cutoff_hz:g} Hz on q, dq"
            + (", tau" if filter_torque else "")
            + (", wrench" if log.wrench is not None else "")
        )
    if log.ddq is None:
        notes.append("ddq = central difference of the " + ("filtered " if cutoff_hz is not None else "") + "dq")

    def cat(i: int) -> np.ndarray | None:
        pieces = [p[i] for p in parts]
        return None if pieces[0] is None else np.concatenate(pieces)  # type: ignore[arg-type]

    t, q, dq, tau, ddq, wrench, tau_raw = (cat(i) for i in range(7))
    assert t is not None and q is not None and dq is not None and tau is not None
    return RobotLog(
        t=t,
        q=q,
        dq=dq,
        tau=tau,
        ddq=ddq,
        wrench=wrench,
        tau_raw=tau_raw if (filter_torque and cutoff_hz is not None) else None,
        source=where,
        notes=log.notes + tuple(notes),
    )


def _preprocess_segment(
    log: RobotLog,
    T: float,
    k: int,
    resample: bool,
    filt: tuple[np.ndarray, np.ndarray, int] | None,
    filter_torque: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, int]:
    """One gap-free segment: (t, q, dq, tau, ddq, wrench, tau_raw, grid points filled) on ``k`` samples."""
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    from scipy.signal import filtfilt

    if resample:
        t = log.t[0] + T * np.arange(k)
        q = CubicHermiteSpline(log.t, log.q, log.dq, axis=0)(t)
        dq = CubicSpline(log.t, log.dq, axis=0)(t)
        tau = _interp(log.t, log.tau, t)
        ddq = None if log.ddq is None else _interp(log.t, log.ddq, t)
        wrench = None if log.wrench is None else _interp(log.t, log.wrench, t)
        tau_raw = _interp(log.t, log.measured_torque, t)
        on_grid = int(np.isin(np.round((log.t - log.t[0]) / T).astype(np.int64), np.arange(k)).sum())
        filled = k - min(on_grid, k)
    else:
        t, q, dq, tau, ddq, wrench = log.t, log.q, log.dq, log.tau, log.ddq, log.wrench
        tau_raw, filled = log.measured_torque, 0
    if filt is not None:
        b, a, padlen = filt
        pad = min(padlen, t.size - 1)
        q = filtfilt(b, a, q, axis=0, padlen=pad)
        dq = filtfilt(b, a, dq, axis=0, padlen=pad)
        if filter_torque:
            tau = filtfilt(b, a, tau, axis=0, padlen=pad)
        if wrench is not None:
            wrench = filtfilt(b, a, wrench, axis=0, padlen=pad)
        if ddq is not None:
            ddq = filtfilt(b, a, ddq, axis=0, padlen=pad)
    if ddq is None:
        ddq = np.gradient(dq, T, axis=0)
    return t, q, dq, tau, ddq, wrench, tau_raw, filled


def _interp(t: np.ndarray, y: np.ndarray, tn: np.ndarray) -> np.ndarray:
    out = np.empty((tn.size, y.shape[1]))
    for j in range(y.shape[1]):
        out[:, j] = np.interp(tn, t, y[:, j])
    return out
