"""Robot logs in: load CSV / Parquet / npz, validate, repair, resample, filter and differentiate.

Log schema (SI units, the robot model's joint order, joints numbered from 1 as in the paper):

======================  ==========================================================  ========
column (CSV, Parquet)   meaning                                                     required
======================  ==========================================================  ========
``t``                   time [s], non-decreasing                                    yes
``q_1`` .. ``q_n``      joint positions [rad]                                       yes
``dq_1`` .. ``dq_n``    joint velocities [rad/s]                                    yes
``tau_1`` .. ``tau_n``  measured joint (motor) torques tau_m [Nm]                   yes
``ddq_1`` .. ``ddq_n``  joint accelerations [rad/s^2] (else derived, see below)     no
``fx fy fz mx my mz``   wrist wrench on the arm beyond the sensor, sensor frame      no
                        [N, Nm] (removed from the torques as tau_ext, eq. (14))
======================  ==========================================================  ========

An ``.npz`` file holds arrays instead of columns: ``t`` (N,), ``q``, ``dq``, ``tau`` (N, n), optional
``ddq`` (N, n) and ``wrench`` (N, 6).

Validation is strict and every error names the file, the column or row and the problem
(:class:`~reflexarm.errors.DataError`): missing or unknown columns, joint columns that are not 1..n,
a joint count that does not match the robot, NaN/inf, time going backwards. Rows are reported 0-based
among the data rows (for a CSV file, row r is on line r + 2).

Real logs are messy, so two defects are repaired (with a :class:`LogRepairWarning` saying what was done)
instead of rejected, unless ``repair=False``:

* **exact repeats**: a row whose every value except the time equals the previous row is the same robot
  sample read twice by the host; it is dropped.
* **jittery host time stamps**: when the steps are not (close to) multiples of one period, the samples
  are re-timed on a grid of the nominal period T (the median step). The log itself says how many periods
  lie between two samples where that is unambiguous: the measured displacement over the mean measured
  velocity, ``dt = (dq_mean . delta_q) / |dq_mean|^2``, when it lands within 0.2 T of a whole number
  of periods. Those step counts are aligned with the host clock (which is right on average but jitters
  locally) by a Viterbi search over each sample's tick (``_align_ticks``), so the result neither
  drifts from the host clock nor follows its jitter. The warning reports the largest shift and how much
  better delta_q and dq dt agree afterwards; if no alignment stays within :data:`MAX_RETIME_SHIFT`
  periods of the host clock, the host time is kept.

:func:`preprocess_log` then resamples to a uniform grid (positions by cubic Hermite interpolation with
the measured velocities as slopes, velocities by a cubic spline, the other signals linearly; only gaps
are actually filled when the log is already on the grid) and filters with a zero-phase Butterworth low-
pass (``scipy.signal.filtfilt``, order 4, default cutoff :data:`DEFAULT_CUTOFF_HZ` for q, dq and ddq),
and derives ddq as the central difference of the filtered dq. The torques are filtered with the same
filter for identification (the regressor and the torque then see the same filter, Gautier's parallel
filtering); the raw torques stay available for validation.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from reflexarm.errors import DataError

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "LogRepairWarning",
    "RobotLog",
    "load_log",
    "preprocess_log",
    "save_log",
]

#: Default low-pass cutoff for q, dq, ddq and the identification torques [Hz]. Identification
#: trajectories have their content below a few Hz (the paper's Fourier trajectories, Gaz's 0.075 Hz x 5
#: harmonics); 10 Hz keeps it undistorted while removing most of the differentiation noise.
DEFAULT_CUTOFF_HZ = 10.0
#: Butterworth order of the zero-phase filter (applied forwards and backwards: effective order 8).
DEFAULT_FILTER_ORDER = 4
#: Re-timing is refused if it would move a sample by more than this many nominal periods.
MAX_RETIME_SHIFT = 6.0
#: A step counts as regular if it is within this fraction of a period of a whole number of periods.
_TICK_TOLERANCE = 0.2

WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")
_JOINT_GROUPS = ("q", "dq", "tau", "ddq")
_COL_RE = re.compile(r"^(q|dq|ddq|tau)_(\d+)$")


class LogRepairWarning(UserWarning):
    """A log was repaired (repeated rows dropped, time stamps re-timed); the message says what was done."""


@dataclass(frozen=True)
class RobotLog:
    """A validated robot log: strictly increasing time, equal lengths, finite values.

    Attributes:
        t: time (N,) [s], strictly increasing.
        q: joint positions (N, n) [rad].
        dq: joint velocities (N, n) [rad/s].
        tau: measured joint torques tau_m (N, n) [Nm].
        ddq: joint accelerations (N, n) [rad/s^2], or None (see :func:`preprocess_log`).
        wrench: wrist wrench (N, 6) [N, Nm] in the sensor frame, or None.
        tau_raw: the unfiltered torques when ``tau`` was filtered by :func:`preprocess_log`, else None.
        source: where the log came from (file name), used in messages.
        notes: what was done to the data (repairs, resampling, filter cutoffs), in order.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    ddq: np.ndarray | None = None
    wrench: np.ndarray | None = None
    tau_raw: np.ndarray | None = None
    source: str = "log"
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        where = self.source
        t = np.asarray(self.t, dtype=float).reshape(-1)
        N = t.size
        if N < 2:
            raise DataError(f"{where}: a log needs at least 2 samples; got {N}")
        arrays: dict[str, np.ndarray | None] = {"t": t}  # validated arrays, set on self at the end
        n = None
        for name in ("q", "dq", "tau", "ddq", "tau_raw"):
            value = getattr(self, name)
            if value is None:
                arrays[name] = None
                continue
            arr = np.asarray(value, dtype=float)
            if arr.ndim == 1:
                arr = arr[:, None]
            if arr.ndim != 2 or arr.shape[0] != N:
                raise DataError(f"{where}: {name} must have shape ({N}, n) like t; got {arr.shape}")
            if n is None:
                n = arr.shape[1]
            elif arr.shape[1] != n:
                raise DataError(f"{where}: {name} has {arr.shape[1]} joints; q has {n}")
            arrays[name] = arr
        if self.wrench is not None:
            w = np.asarray(self.wrench, dtype=float)
            if w.shape != (N, 6):
                raise DataError(f"{where}: wrench must have shape ({N}, 6); got {w.shape}")
            arrays["wrench"] = w
        else:
            arrays["wrench"] = None
        for name, checked in arrays.items():
            if checked is None:
                continue
            bad = ~np.isfinite(checked)
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                col = "" if checked.ndim == 1 else f"[:, {int(np.argwhere(bad)[0][1])}]"
                raise DataError(f"{where}: {name}{col} is {_describe(checked[bad][0])} at row {row}")
        steps = np.diff(t)
        if np.any(steps <= 0):
            row = int(np.argmax(steps <= 0)) + 1
            raise DataError(
                f"{where}: time is not strictly increasing at row {row}: t = {t[row]!r} s after {t[row - 1]!r} s"
            )
        for name, value in arrays.items():
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ facts
    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.q.shape[1])

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def duration(self) -> float:
        """t[-1] - t[0] [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def period(self) -> float:
        """Median time step [s]."""
        return float(np.median(np.diff(self.t)))

    @property
    def is_uniform(self) -> bool:
        """True if every step equals the median step within 1e-6 relative."""
        dt = np.diff(self.t)
        return bool(np.all(np.abs(dt - np.median(dt)) <= 1e-6 * np.median(dt)))

    @property
    def measured_torque(self) -> np.ndarray:
        """The unfiltered measured torques (``tau_raw`` if the log was filtered, else ``tau``)."""
        return self.tau if self.tau_raw is None else self.tau_raw

    # ------------------------------------------------------------------ pieces
    def select(self, rows: slice | np.ndarray) -> RobotLog:
        """The log restricted to some rows (a slice or an index/boolean array), same notes."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return replace(
            self,
            t=self.t[rows],
            q=self.q[rows],
            dq=self.dq[rows],
            tau=self.tau[rows],
            ddq=pick(self.ddq),
            wrench=pick(self.wrench),
            tau_raw=pick(self.tau_raw),
        )

    def split(self, fraction: float) -> tuple[RobotLog, RobotLog]:
        """(first ``fraction`` of the samples, the rest), e.g. 0.6 for identify / validate."""
        if not 0.0 < fraction < 1.0:
            raise DataError(f"split fraction must be in (0, 1); got {fraction!r}")
        k = int(round(fraction * len(self)))
        return self.select(slice(0, k)), self.select(slice(k, None))

    def with_notes(self, *notes: str) -> RobotLog:
        return replace(self, notes=self.notes + tuple(notes))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        t: npt.ArrayLike,
        q: npt.ArrayLike,
        dq: npt.ArrayLike,
        tau: npt.ArrayLike,
        *,
        ddq: npt.ArrayLike | None = None,
        wrench: npt.ArrayLike | None = None,
        source: str = "arrays",
        n_joints: int | None = None,
        repair: bool = True,
        period: float | None = None,
    ) -> RobotLog:
        """Build a log from arrays with the same checks and repairs as :func:`load_log`."""
        data = {
            "t": np.asarray(t, dtype=float).reshape(-1),
            "q": _as2d(q),
            "dq": _as2d(dq),
            "tau": _as2d(tau),
        }
        if ddq is not None:
            data["ddq"] = _as2d(ddq)
        if wrench is not None:
            data["wrench"] = _as2d(wrench)
        return _finish(data, source, n_joints, repair, period)

    def to_columns(self) -> dict[str, np.ndarray]:
        """The log as named columns of the schema (for CSV / Parquet)."""
        cols: dict[str, np.ndarray] = {"t": self.t}
        for name in ("q", "dq", "tau", "ddq"):
            arr = getattr(self, name)
            if arr is None:
                continue
            for j in range(self.n):
                cols[f"{name}_{j + 1}"] = arr[:, j]
        if self.wrench is not None:
            for k, c in enumerate(WRENCH_COLUMNS):
                cols[c] = self.wrench[:, k]
        return cols


def _describe(x: float) -> str:
    return "NaN" if np.isnan(x) else ("+inf" if x > 0 else "-inf")


def _as2d(x: npt.ArrayLike) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    return arr[:, None] if arr.ndim == 1 else arr


# ---------------------------------------------------------------------------------------------- loading
def load_log(
    path: str | os.PathLike[str],
    *,
    n_joints: int | None = None,
    repair: bool = True,
    period: float | None = None,
) -> RobotLog:
    """Load a log from ``.csv``, ``.parquet`` or ``.npz`` (schema in the module docstring).

    Args:
        path: the file.
        n_joints: the robot's joint count (e.g. ``robot.n``); a log with another count is rejected.
        repair: drop exact repeats and re-time jittery time stamps (with a warning); if False such
            logs raise :class:`DataError`.
        period: nominal sample period [s] for re-timing (default: the median step).

    Raises:
        DataError: unreadable file, missing or unknown columns, wrong joint count, NaN/inf, time going
            backwards; the message names the file, the column or row and the problem.
    """
    p = Path(path)
    where = p.name
    if not p.is_file():
        raise DataError(f"log file {str(p)!r} does not exist")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        data = _read_npz(p)
    elif suffix in (".csv", ".parquet", ".pq"):
        data = _read_table(p, suffix)
    else:
        raise DataError(f"{where}: unknown log format {suffix!r}; use .csv, .parquet or .npz")
    return _finish(data, where, n_joints, repair, period)


def _read_table(p: Path, suffix: str) -> dict[str, np.ndarray]:
    import pandas as pd

    where = p.name
    try:
        df = pd.read_csv(p) if suffix == ".csv" else pd.read_parquet(p)
    except Exception as e:  # pandas/pyarrow raise many types; explain and chain
        raise DataError(f"{where}: cannot read the file as {suffix[1:]}: {e}") from e
    columns = [str(c).strip() for c in df.columns]
    df.columns = columns
    dup = sorted({c for c in columns if columns.count(c) > 1})
    if dup:
        raise DataError(f"{where}: duplicated column(s) {', '.join(map(repr, dup))}")
    joint_cols: dict[str, dict[int, str]] = {g: {} for g in _JOINT_GROUPS}
    unknown = []
    for c in columns:
        m = _COL_RE.match(c)
        if m:
            joint_cols[m.group(1)][int(m.group(2))] = c
        elif c not in ("t", *WRENCH_COLUMNS):
            unknown.append(c)
    if unknown:
        raise DataError(
            f"{where}: unexpected column(s) {', '.join(map(repr, unknown))}; the schema has t, q_i, dq_i, tau_i, "
            f"optional ddq_i and {', '.join(WRENCH_COLUMNS)} (i = 1..n)"
        )
    if "t" not in columns:
        raise DataError(f"{where}: column 't' missing; found: {', '.join(columns)}")
    idx = sorted(joint_cols["q"]) or sorted(joint_cols["tau"]) or sorted(joint_cols["dq"])
    if not idx:
        raise DataError(f"{where}: no joint columns (q_1, dq_1, tau_1, ...); found: {', '.join(columns)}")
    n = max(idx)
    for g in ("q", "dq", "tau"):
        for j in range(1, n + 1):
            if j not in joint_cols[g]:
                raise DataError(f"{where}: column '{g}_{j}' missing; found: {', '.join(columns)}")
    for g in _JOINT_GROUPS:
        extra = sorted(j for j in joint_cols[g] if j < 1 or j > n)
        if extra:
            raise DataError(
                f"{where}: column(s) {', '.join(f'{g}_{j}' for j in extra)} beyond the {n} joints of q_1..q_{n}"
            )
    if joint_cols["ddq"] and len(joint_cols["ddq"]) != n:
        missing = [f"ddq_{j}" for j in range(1, n + 1) if j not in joint_cols["ddq"]]
        raise DataError(f"{where}: column(s) {', '.join(missing)} missing (give all ddq_i or none)")
    have_w = [c for c in WRENCH_COLUMNS if c in columns]
    if have_w and len(have_w) != 6:
        missing = [c for c in WRENCH_COLUMNS if c not in columns]
        raise DataError(f"{where}: wrench column(s) {', '.join(missing)} missing (give all six or none)")
    out: dict[str, np.ndarray] = {}
    for c in columns:
        col = df[c]
        try:
            values = np.asarray(col.to_numpy(dtype=float, na_value=np.nan), dtype=float)
        except (TypeError, ValueError) as e:
            bad = next((i for i, v in enumerate(col.tolist()) if not _is_number(v)), None)
            raise DataError(f"{where}: column {c!r} row {bad}: {col.iloc[bad]!r} is not a number") from e
        bad = ~np.isfinite(values)
        if bad.any():
            r = int(np.argmax(bad))
            raise DataError(f"{where}: column {c!r} row {r} is {_describe(values[r])}")
        out[c] = values
    data = {"t": out["t"]}
    for g in _JOINT_GROUPS:
        if joint_cols[g]:
            data[g] = np.column_stack([out[f"{g}_{j}"] for j in range(1, n + 1)])
    if have_w:
        data["wrench"] = np.column_stack([out[c] for c in WRENCH_COLUMNS])
    return data


def _is_number(v: object) -> bool:
    try:
        float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def _read_npz(p: Path) -> dict[str, np.ndarray]:
    where = p.name
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:
        raise DataError(f"{where}: cannot read the file as npz: {e}") from e
    allowed = ("t", "q", "dq", "tau", "ddq", "wrench")
    unknown = [k for k in arrays if k not in allowed]
    if unknown:
        raise DataError(
            f"{where}: unexpected array(s) {', '.join(map(repr, unknown))}; an npz log holds t, q, dq, tau and "
            "optionally ddq, wrench"
        )
    for k in ("t", "q", "dq", "tau"):
        if k not in arrays:
            raise DataError(f"{where}: array {k!r} missing; found: {', '.join(arrays) or 'nothing'}")
    out = {}
    for k, a in arrays.items():
        try:
            arr = np.asarray(a, dtype=float)
        except (TypeError, ValueError) as e:
            raise DataError(f"{where}: array {k!r} is not numeric ({a.dtype})") from e
        out[k] = arr
    return out


def _finish(
    data: dict[str, np.ndarray], where: str, n_joints: int | None, repair: bool, period: float | None
) -> RobotLog:
    t = np.asarray(data["t"], dtype=float).reshape(-1)
    N = t.size
    q = data["q"]
    n = q.shape[1] if q.ndim == 2 else 1
    for k in ("q", "dq", "tau", "ddq"):
        if k in data:
            a = data[k]
            if a.ndim != 2 or a.shape[0] != N:
                raise DataError(f"{where}: {k} must have shape ({N}, n) with N = len(t); got {a.shape}")
            if a.shape[1] != n:
                raise DataError(f"{where}: {k} has {a.shape[1]} joints, q has {n}")
    if "wrench" in data and data["wrench"].shape != (N, 6):
        raise DataError(f"{where}: wrench must have shape ({N}, 6); got {data['wrench'].shape}")
    if n_joints is not None and n != n_joints:
        raise DataError(f"{where}: the log has {n} joints (q_1..q_{n}); the robot has {n_joints}")
    for k, a in data.items():
        bad = ~np.isfinite(a)
        if bad.any():
            pos = np.argwhere(bad)[0]
            col = k if a.ndim == 1 else (WRENCH_COLUMNS[pos[1]] if k == "wrench" else f"{k}_{pos[1] + 1}")
            raise DataError(f"{where}: column {col!r} row {pos[0]} is {_describe(a[tuple(pos)])}")
    if N < 2:
        raise DataError(f"{where}: a log needs at least 2 samples; got {N}")
    steps = np.diff(t)
    back = np.flatnonzero(steps < 0)
    if back.size:
        r = int(back[0]) + 1
        raise DataError(
            f"{where}: time goes backwards at row {r}: t = {t[r]:.9g} s after {t[r - 1]:.9g} s "
            f"({back.size} such row(s))"
        )
    notes: list[str] = []
    # exact repeats: every value but the time equals the previous row
    values = np.column_stack([data[k] for k in ("q", "dq", "tau", "ddq", "wrench") if k in data])
    repeat = np.r_[False, np.all(values[1:] == values[:-1], axis=1)]
    if repeat.any():
        if not repair:
            r = int(np.argmax(repeat))
            raise DataError(
                f"{where}: row {r} repeats row {r - 1} exactly ({int(repeat.sum())} such rows); "
                "load with repair=True to drop them"
            )
        keep = ~repeat
        data = {k: v[keep] for k, v in data.items()}
        msg = (
            f"{where}: dropped {int(repeat.sum()):,} rows that exactly repeat the previous row (same q, dq, tau: "
            f"the host read one robot sample twice); {int(keep.sum()):,} of {N:,} rows remain"
        )
        warnings.warn(msg, LogRepairWarning, stacklevel=3)
        notes.append(msg)
        t = data["t"]
    steps = np.diff(t)
    if np.any(steps <= 0):
        if not repair:
            r = int(np.argmax(steps <= 0)) + 1
            raise DataError(f"{where}: time does not increase at row {r}: t = {t[r]:.9g} s twice")
    if period is not None:
        T = float(period)
    elif np.any(steps > 0):
        T = _estimate_period(t, data["q"], data["dq"])
    else:
        raise DataError(f"{where}: all time stamps are equal")
    ticks = steps / T
    irregular = np.abs(ticks - np.maximum(np.round(ticks), 1.0)) > _TICK_TOLERANCE
    if irregular.any() or np.any(steps <= 0):
        if not repair:
            r = int(np.argmax(irregular | (steps <= 0))) + 1
            raise DataError(
                f"{where}: irregular time step at row {r}: {steps[r - 1] * 1e3:.3g} ms for a {T * 1e3:.3g} ms period "
                f"({int(irregular.sum())} such steps); load with repair=True to re-time"
            )
        new_t, msg = _retime(t, data["q"], data["dq"], T, where)
        warnings.warn(msg, LogRepairWarning, stacklevel=3)
        notes.append(msg)
        data["t"] = new_t
    log = RobotLog(
        t=data["t"],
        q=data["q"],
        dq=data["dq"],
        tau=data["tau"],
        ddq=data.get("ddq"),
        wrench=data.get("wrench"),
        source=where,
        notes=tuple(notes),
    )
    return log


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


# ---------------------------------------------------------------------------------------------- saving
def save_log(log: RobotLog, path: str | os.PathLike[str]) -> Path:
    """Write ``log`` as ``.csv``, ``.parquet`` or ``.npz`` (by suffix) in the documented schema."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    suffix = p.suffix.lower()
    if suffix == ".npz":
        arrays = {"t": log.t, "q": log.q, "dq": log.dq, "tau": log.measured_torque}
        if log.ddq is not None:
            arrays["ddq"] = log.ddq
        if log.wrench is not None:
            arrays["wrench"] = log.wrench
        np.savez_compressed(p, **arrays)  # type: ignore[arg-type]
        return p
    import pandas as pd

    cols = replace(log, tau=log.measured_torque, tau_raw=None).to_columns()
    df = pd.DataFrame(cols)
    if suffix == ".csv":
        df.to_csv(p, index=False, float_format="%.10g")
    elif suffix in (".parquet", ".pq"):
        df.to_parquet(p, index=False)
    else:
        raise DataError(f"{p.name}: unknown log format {suffix!r}; use .csv, .parquet or .npz")
    return p


# ---------------------------------------------------------------------------------------------- preprocessing
def preprocess_log(
    log: RobotLog,
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    order: int = DEFAULT_FILTER_ORDER,
    period: float | None = None,
    filter_torque: bool = True,
) -> RobotLog:
    """Uniform grid, zero-phase low-pass filter, ddq by differentiation.

    Args:
        log: a validated log (possibly with gaps).
        cutoff_hz: Butterworth cutoff for q, dq (and ddq, derived from the filtered dq) [Hz]; None: no
            filtering (ddq is then the central difference of the raw dq).
        order: Butterworth order (applied forwards and backwards by ``filtfilt``: zero phase).
        period: grid period [s] (default: the log's median step).
        filter_torque: filter the torques with the same filter (kept raw in ``tau_raw``).

    Returns:
        A new log on the uniform grid with ``ddq`` filled (a ddq given in the log is kept, resampled).
    """
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    from scipy.signal import butter, filtfilt

    T = log.period if period is None else float(period)
    if not T > 0:
        raise DataError(f"{log.source}: resampling period must be positive; got {period!r}")
    notes = []
    if log.is_uniform and period is None:
        t = log.t
        q, dq, tau = log.q, log.dq, log.tau
        ddq, wrench = log.ddq, log.wrench
    else:
        k = int(np.floor((log.t[-1] - log.t[0]) / T + 1e-9)) + 1
        t = log.t[0] + T * np.arange(k)
        q = CubicHermiteSpline(log.t, log.q, log.dq, axis=0)(t)
        dq = CubicSpline(log.t, log.dq, axis=0)(t)
        tau = _interp(log.t, log.tau, t)
        ddq = None if log.ddq is None else _interp(log.t, log.ddq, t)
        wrench = None if log.wrench is None else _interp(log.t, log.wrench, t)
        on_grid = np.isin(np.round((log.t - log.t[0]) / T).astype(np.int64), np.arange(k)).sum()
        notes.append(
            f"resampled {len(log):,} samples to a uniform {T * 1e3:.4g} ms grid of {k:,} samples "
            f"(q cubic Hermite with dq as slopes, dq cubic spline, other signals linear; "
            f"{k - min(on_grid, k):,} grid points filled)"
        )
    fs = 1.0 / T
    tau_raw = log.measured_torque if (log.is_uniform and period is None) else _interp(log.t, log.measured_torque, t)
    if cutoff_hz is not None:
        if not 0 < cutoff_hz < 0.5 * fs:
            raise DataError(
                f"{log.source}: filter cutoff {cutoff_hz!r} Hz must be between 0 and the Nyquist frequency "
                f"{0.5 * fs:.4g} Hz"
            )
        b, a = butter(order, cutoff_hz / (0.5 * fs))
        # odd extension over two periods of the cutoff, so the edge transient of the filter dies out
        padlen = min(max(3 * max(len(a), len(b)), int(round(2 * fs / cutoff_hz))), t.size - 1)
        q = filtfilt(b, a, q, axis=0, padlen=padlen)
        dq = filtfilt(b, a, dq, axis=0, padlen=padlen)
        if filter_torque:
            tau = filtfilt(b, a, tau, axis=0, padlen=padlen)
        if wrench is not None:
            wrench = filtfilt(b, a, wrench, axis=0, padlen=padlen)
        notes.append(
            f"zero-phase Butterworth low-pass (order {order}, forwards and backwards) at {cutoff_hz:g} Hz on q, dq"
            + (", tau" if filter_torque else "")
            + (", wrench" if wrench is not None else "")
        )
    if ddq is None:
        ddq = np.gradient(dq, T, axis=0)
        notes.append("ddq = central difference of the " + ("filtered " if cutoff_hz is not None else "") + "dq")
    elif cutoff_hz is not None:
        ddq = filtfilt(b, a, ddq, axis=0, padlen=padlen)
    return RobotLog(
        t=t,
        q=q,
        dq=dq,
        tau=tau,
        ddq=ddq,
        wrench=wrench,
        tau_raw=tau_raw if (filter_torque and cutoff_hz is not None) else None,
        source=log.source,
        notes=log.notes + tuple(notes),
    )


def _interp(t: np.ndarray, y: np.ndarray, tn: np.ndarray) -> np.ndarray:
    out = np.empty((tn.size, y.shape[1]))
    for j in range(y.shape[1]):
        out[:, j] = np.interp(tn, t, y[:, j])
    return out
