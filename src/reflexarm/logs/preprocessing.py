"""preprocess_log: uniform grid per gap-free segment, zero-phase low-pass filter, ddq by differentiation.

See :mod:`reflexarm.logs` for the whole pipeline; :func:`preprocess_log` is re-exported there.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.robot_log import LogRepairWarning, RobotLog

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_FILTER_ORDER",
    "DEFAULT_MAX_GAP_PERIODS",
    "MAX_GRID_FACTOR",
    "PreprocessingPlan",
    "Segment",
    "plan_preprocessing",
    "preprocess_log",
    "preprocess_window",
]

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
    plan = plan_preprocessing(
        log.t, log.source, cutoff_hz=cutoff_hz, order=order, period=period, max_gap=max_gap,
        has_ddq=log.ddq is not None, has_wrench=log.wrench is not None, filter_torque=filter_torque, stacklevel=3,
    )  # fmt: skip
    parts = [preprocess_window(log.select(slice(seg.i0, seg.i1)), plan, seg, 0, seg.k) for seg in plan.segments]

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
        tau_raw=tau_raw if plan.keeps_raw_torque else None,
        source=log.source,
        notes=log.notes + plan.notes,
    )


class Segment(NamedTuple):
    """A gap-free run of the log's samples ``[i0, i1)`` and its grid: ``k`` samples ``t0 + period * i``."""

    i0: int
    i1: int
    k: int
    t0: float
    period: float


@dataclass(frozen=True)
class PreprocessingPlan:
    """What :func:`preprocess_log` does, decided from the time stamps alone (so that a log read in blocks,
    :mod:`reflexarm.logs.blocks`, is preprocessed exactly as the whole log): the kept segments and their grids,
    whether the samples are resampled, the filter ``(b, a, padlen)`` and the notes."""

    segments: tuple[Segment, ...]
    resample: bool
    filt: tuple[np.ndarray, np.ndarray, int] | None
    filter_torque: bool
    notes: tuple[str, ...]

    @property
    def keeps_raw_torque(self) -> bool:
        return self.filter_torque and self.filt is not None

    @property
    def size(self) -> int:
        """Samples of the preprocessed log."""
        return sum(s.k for s in self.segments)


def plan_preprocessing(
    t: np.ndarray,
    where: str,
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    period: float | None = None,
    max_gap: float | None = None,
    has_ddq: bool = False,
    has_wrench: bool = False,
    filter_torque: bool = True,
    stacklevel: int = 2,
) -> PreprocessingPlan:
    """The plan of :func:`preprocess_log` for a log with time stamps ``t`` (arguments as there); a dropped
    short segment warns (:class:`LogRepairWarning`) here."""
    steps = np.diff(t)
    log_period = float(np.median(steps))
    T = log_period if period is None else float(period)
    if not (np.isfinite(T) and T > 0):
        raise DataError(f"{where}: resampling period must be positive; got {period!r}")
    gap = DEFAULT_MAX_GAP_PERIODS * log_period if max_gap is None else float(max_gap)
    if not (np.isfinite(gap) and gap >= T):
        raise DataError(f"{where}: max_gap must be at least the grid period {T:.6g} s; got {max_gap!r}")
    filt = _filter(where, cutoff_hz, order, 1.0 / T)
    min_len = 3 if filt is None else filt[2] + 1
    uniform = bool(np.all(np.abs(steps - log_period) <= 1e-6 * log_period))
    resample = not (uniform and period is None)
    cuts = np.flatnonzero(steps > gap * (1 + 1e-9)) + 1
    edges = np.r_[0, cuts, t.size]
    spans = [(int(i0), int(i1)) for i0, i1 in zip(edges[:-1], edges[1:], strict=True)]
    sizes = _grid_sizes(t, spans, T, resample, period is None)
    if sum(sizes) > MAX_GRID_FACTOR * t.size:
        raise DataError(
            f"{where}: resampling {t.size:,} samples at a {T:.6g} s period would need a grid of {sum(sizes):,} "
            f"samples (more than {MAX_GRID_FACTOR} x the log); use a period near the log's own {log_period:.6g} s"
        )
    notes: list[str] = []
    if cuts.size:
        longest = int(np.argmax(steps[cuts - 1]))
        notes.append(
            f"split at {cuts.size:,} gap(s) longer than {gap:.6g} s (longest {steps[cuts[longest] - 1]:.6g} s after "
            f"t = {t[cuts[longest] - 1]:.6g} s) into {len(spans):,} segments, each resampled and filtered "
            "separately: nothing is interpolated or filtered across a gap"
        )
    kept = _drop_short(where, spans, sizes, min_len, notes, stacklevel + 1)
    fit = resample and period is None
    segments = tuple(
        Segment(i0, i1, k, float(t[i0]), (t[i1 - 1] - t[i0]) / (k - 1) if fit else T) for (i0, i1), k in kept
    )
    if resample:
        notes.append(_resample_note(t, segments, T, fit))
    if filt is not None:
        notes.append(
            f"zero-phase Butterworth low-pass (order {order}, forwards and backwards) at {cutoff_hz:g} Hz on q, dq"
            + (", tau" if filter_torque else "")
            + (", wrench" if has_wrench else "")
        )
    if not has_ddq:
        notes.append("ddq = central difference of the " + ("filtered " if filt is not None else "") + "dq")
    return PreprocessingPlan(segments, resample, filt, filter_torque, tuple(notes))


def _filter(where: str, cutoff_hz: float | None, order: int, fs: float) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The Butterworth filter (b, a) and its pad length, or None without a cutoff."""
    from scipy.signal import butter

    if cutoff_hz is None:
        return None
    if not 0 < cutoff_hz < 0.5 * fs:
        raise DataError(
            f"{where}: filter cutoff {cutoff_hz!r} Hz must be between 0 and the Nyquist frequency {0.5 * fs:.4g} Hz"
        )
    b, a = butter(order, cutoff_hz / (0.5 * fs))
    # odd extension over two periods of the cutoff, so the edge transient of the filter dies out
    padlen = max(3 * max(len(a), len(b)), int(round(2 * fs / cutoff_hz)))
    return b, a, padlen


def _grid_sizes(t: np.ndarray, spans: list[tuple[int, int]], T: float, resample: bool, fit: bool) -> list[int]:
    """Grid samples per segment, known before anything is allocated.

    With the log's own period, each segment's grid spans the segment exactly (its period is the span over
    the nearest whole number of periods): a grid that stopped short of the last sample would leave the
    samples after it outside the states (validation of a jittery log, --split). A period the caller gives
    is kept as given."""
    if not resample:
        return [i1 - i0 for i0, i1 in spans]
    if fit:
        return [max(int(round((t[i1 - 1] - t[i0]) / T)), 1) + 1 for i0, i1 in spans]
    return [int(np.floor((t[i1 - 1] - t[i0]) / T + 1e-6)) + 1 for i0, i1 in spans]


def _drop_short(
    where: str, spans: list[tuple[int, int]], sizes: list[int], min_len: int, notes: list[str], stacklevel: int
) -> list[tuple[tuple[int, int], int]]:
    """The segments with at least ``min_len`` grid samples (the others dropped with a warning and a note)."""
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
        warnings.warn(msg, LogRepairWarning, stacklevel=stacklevel)
        notes.append(msg)
    return kept


def _resample_note(t: np.ndarray, segments: tuple[Segment, ...], T: float, fit: bool) -> str:
    """What resampling did, with the grid points filled (not on a sample of the log)."""
    filled = 0
    for s in segments:
        ticks = np.round((t[s.i0 : s.i1] - s.t0) / s.period)
        filled += s.k - min(int(np.count_nonzero((ticks >= 0) & (ticks < s.k))), s.k)
    n_in = sum(s.i1 - s.i0 for s in segments)
    periods = [s.period for s in segments]
    return (
        f"resampled {n_in:,} samples to a uniform {T * 1e3:.4g} ms grid of {sum(s.k for s in segments):,} samples "
        + (
            f"(each segment's grid spans it from its first to its last sample: period {min(periods) * 1e3:.6g}"
            f"..{max(periods) * 1e3:.6g} ms) "
            if fit
            else ""
        )
        + "(q cubic Hermite with dq as slopes, dq cubic spline, other signals linear; "
        + f"{filled:,} grid points filled)"
    )


def preprocess_window(
    log: RobotLog, plan: PreprocessingPlan, seg: Segment, g0: int, g1: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Grid samples ``[g0, g1)`` of segment ``seg`` from ``log``, the segment's samples that cover them:
    (t, q, dq, tau, ddq, wrench, tau_raw). With the whole segment (``g0 = 0``, ``g1 = seg.k``) this is
    the segment of :func:`preprocess_log`; a window inside it gives the same values away from its edges,
    where the filter's and the spline's edge transients have died out (see :mod:`reflexarm.logs.blocks`)."""
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    from scipy.signal import filtfilt

    if plan.resample:
        t = seg.t0 + seg.period * np.arange(g0, g1)
        q = CubicHermiteSpline(log.t, log.q, log.dq, axis=0)(t)
        dq = CubicSpline(log.t, log.dq, axis=0)(t)
        tau = _interp(log.t, log.tau, t)
        ddq = None if log.ddq is None else _interp(log.t, log.ddq, t)
        wrench = None if log.wrench is None else _interp(log.t, log.wrench, t)
        tau_raw = _interp(log.t, log.measured_torque, t)
    else:
        t, q, dq, tau, ddq, wrench = log.t, log.q, log.dq, log.tau, log.ddq, log.wrench
        tau_raw = log.measured_torque
    if plan.filt is not None:
        b, a, padlen = plan.filt
        pad = min(padlen, seg.k - 1)
        q = filtfilt(b, a, q, axis=0, padlen=pad)
        dq = filtfilt(b, a, dq, axis=0, padlen=pad)
        if plan.filter_torque:
            tau = filtfilt(b, a, tau, axis=0, padlen=pad)
        if wrench is not None:
            wrench = filtfilt(b, a, wrench, axis=0, padlen=pad)
        if ddq is not None:
            ddq = filtfilt(b, a, ddq, axis=0, padlen=pad)
    if ddq is None:
        ddq = np.gradient(dq, seg.period, axis=0)
    return t, q, dq, tau, ddq, wrench, tau_raw


def _interp(t: np.ndarray, y: np.ndarray, tn: np.ndarray) -> np.ndarray:
    out = np.empty((tn.size, y.shape[1]))
    for j in range(y.shape[1]):
        out[:, j] = np.interp(tn, t, y[:, j])
    return out
