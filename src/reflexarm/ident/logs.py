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
a joint count that does not match the robot, NaN/inf, time going backwards, a column or array whose
dtype is not a number (booleans, text, objects, complex, dates: a boolean column is not taken as 0/1),
values beyond the absolute plausibility bounds of :mod:`reflexarm.ident.plausibility` (e.g. |tau| >
1e6 Nm; :class:`~reflexarm.errors.ImplausibleDataError` lists the rows, columns and values). Rows are
reported 0-based among the data rows (for a CSV file, row r is on line r + 2). The bounds relative to a
robot's limits are applied by :func:`~reflexarm.ident.identify_dynamics`, which knows the robot.

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
are actually filled when the log is already on the grid). Gaps longer than ``max_gap`` (default
:data:`~reflexarm.ident.preprocessing.DEFAULT_MAX_GAP_PERIODS` periods) are not filled: they split the
log into segments, each resampled, filtered and differentiated on its own, and the grid's size is
checked against :data:`~reflexarm.ident.preprocessing.MAX_GRID_FACTOR` before anything is allocated.
It then filters with a zero-phase Butterworth low-pass (``scipy.signal.filtfilt``, order 4, default
cutoff :data:`DEFAULT_CUTOFF_HZ` for q, dq and ddq),
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
from reflexarm.ident._retime import _TICK_TOLERANCE, _estimate_period, _retime
from reflexarm.ident.plausibility import check_absolute_bounds

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
        t = _numeric(self.t, where, "t").reshape(-1)
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
            arr = _numeric(value, where, name)
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
            w = _numeric(self.wrench, where, "wrench")
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
        check_absolute_bounds(where, t, arrays)
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
            "t": _numeric(t, source, "t").reshape(-1),
            "q": _as2d(_numeric(q, source, "q")),
            "dq": _as2d(_numeric(dq, source, "dq")),
            "tau": _as2d(_numeric(tau, source, "tau")),
        }
        if ddq is not None:
            data["ddq"] = _as2d(_numeric(ddq, source, "ddq"))
        if wrench is not None:
            data["wrench"] = _as2d(_numeric(wrench, source, "wrench"))
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


#: dtype kinds a log column may have: signed/unsigned integers and floats. Booleans, text, objects,
#: complex numbers, dates and durations are refused: a boolean column taken as 0/1 joint values, or
#: text parsed leniently, is a silent wrong number.
_NUMERIC_KINDS = "iuf"
_KIND_NAMES = {"b": "boolean", "O": "text or Python objects", "U": "text", "S": "bytes", "c": "complex",
               "M": "date-time", "m": "time delta", "V": "raw bytes"}  # fmt: skip


def _refuse_dtype(where: str, what: str, dtype: object, kind: str) -> DataError:
    return DataError(
        f"{where}: {what} has dtype {dtype} ({_KIND_NAMES.get(kind, 'not a number')}); log values must be "
        "integers or floats (SI units): convert the column, e.g. a boolean flag is not a joint value"
    )


def _numeric(x: npt.ArrayLike, where: str, name: str) -> np.ndarray:
    """``x`` as float64, refusing non-numeric dtypes (bool, text, objects, complex) by name."""
    arr = np.asarray(x)
    if arr.dtype.kind not in _NUMERIC_KINDS:
        raise _refuse_dtype(where, f"array {name!r}", arr.dtype, arr.dtype.kind)
    return np.asarray(arr, dtype=float)


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
        kind = str(getattr(col.dtype, "kind", "O"))
        if kind not in _NUMERIC_KINDS:
            bad = next((i for i, v in enumerate(col.tolist()) if not _is_number(v)), None)
            if kind in "OUS" and bad is not None:
                raise DataError(f"{where}: column {c!r} row {bad}: {col.iloc[bad]!r} is not a number")
            raise _refuse_dtype(where, f"column {c!r}", col.dtype, kind)
        try:
            values = np.asarray(col.to_numpy(dtype=float, na_value=np.nan), dtype=float)
        except (TypeError, ValueError) as e:  # pragma: no cover - numeric kinds convert
            raise _refuse_dtype(where, f"column {c!r}", col.dtype, kind) from e
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
    return {k: _numeric(a, where, k) for k, a in arrays.items()}


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
    check_absolute_bounds(where, t, {k: v for k, v in data.items() if k != "t"})
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


# preprocessing lives in its own module; re-exported here, where it has always been imported from
from reflexarm.ident.preprocessing import preprocess_log  # noqa: E402
