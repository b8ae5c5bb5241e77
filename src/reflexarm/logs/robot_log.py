"""A validated robot log (:class:`RobotLog`) and the checks and repairs that build one from raw arrays.

Validation is strict and every error names the file, the column or row and the problem
(:class:`~reflexarm.errors.DataError`): missing or unknown columns, joint columns that are not 1..n,
a joint count that does not match the robot, NaN/inf, time going backwards, a column or array whose
dtype is not a number (booleans, text, objects, complex, dates: a boolean column is not taken as 0/1),
values beyond the absolute plausibility bounds of :mod:`reflexarm.logs.plausibility` (e.g. |tau| >
1e6 Nm; :class:`~reflexarm.errors.ImplausibleDataError` lists the rows, columns and values). Rows are
reported 0-based among the data rows (for a CSV file, row r is on line r + 2). The bounds relative to a
robot's limits are applied by :func:`~reflexarm.ident.identify_dynamics`, which knows the robot.

Real logs are messy, so two defects are repaired (with a :class:`LogRepairWarning` saying what was done)
instead of rejected, unless ``repair=False``:

* **exact repeats**: a row whose every value except the time equals the previous row is the same robot
  sample read twice by the host; it is dropped.
* **jittery host time stamps**: when the steps are not (close to) whole multiples of the period T (always
  the median step), the samples are put on the nearest tick of a grid fitted to the stamps, but only if
  no sample moves by more than half a period, no two samples share a tick, no gap is created from jitter
  and positions and velocities agree no worse; otherwise the log's own stamps are kept (irregular
  sampling is valid; repeated stamps are spread evenly up to the next one). The warning or note says
  which, and why (:mod:`reflexarm.logs._retime`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from reflexarm.errors import DataError
from reflexarm.logs._retime import irregular_steps, retime
from reflexarm.logs.bounds import check_absolute_bounds

__all__ = ["WRENCH_COLUMNS", "LogRepairWarning", "RobotLog", "refuse_time_going_back"]

#: Columns of the wrist wrench in the log schema (see :mod:`reflexarm.logs.files`).
WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")


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


def _repair_time(
    data: dict[str, np.ndarray], where: str, repair: bool, period: float | None, notes: list[str]
) -> np.ndarray:
    """The log's times with irregular steps repaired (re-timed onto the grid or kept, see the module docstring);
    what was done goes to ``notes`` (and a :class:`LogRepairWarning` when a time was changed)."""
    t = data["t"]
    steps = np.diff(t)
    if period is not None:
        T = float(period)
    elif np.any(steps > 0):
        T = float(np.median(steps[steps > 0]))  # the period is the median step, always
    else:
        raise DataError(f"{where}: all time stamps are equal")
    irregular = irregular_steps(steps, T)
    if irregular.any():
        if not repair:
            if np.any(steps <= 0):
                r = int(np.argmax(steps <= 0)) + 1
                raise DataError(f"{where}: time does not increase at row {r}: t = {t[r]:.9g} s twice")
            r = int(np.argmax(irregular)) + 1
            raise DataError(
                f"{where}: irregular time step at row {r}: {steps[r - 1] * 1e3:.3g} ms for a {T * 1e3:.3g} ms period "
                f"({int(irregular.sum())} such steps); load with repair=True to re-time"
            )
        new_t, msg, changed = retime(t, data["q"], data["dq"], T, where, fixed=period is not None)
        if changed:
            warnings.warn(msg, LogRepairWarning, stacklevel=4)
        notes.append(msg)
        return new_t
    return t


def _check_shapes(data: dict[str, np.ndarray], N: int, where: str, n_joints: int | None) -> None:
    """Every joint signal (N, n) with the n of q, the wrench (N, 6), n the robot's ``n_joints`` if given."""
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
        raise DataError(
            f"{where}: the log has {n} joints (q_1..q_{n}); the robot has {n_joints}",
            source=where,
            column="q",
            value=n,
            expected=n_joints,
        )


def _check_finite(data: dict[str, np.ndarray], where: str) -> None:
    """The first NaN or inf, by column and row, is a DataError."""
    for k, a in data.items():
        bad = ~np.isfinite(a)
        if bad.any():
            pos = np.argwhere(bad)[0]
            col = k if a.ndim == 1 else (WRENCH_COLUMNS[pos[1]] if k == "wrench" else f"{k}_{pos[1] + 1}")
            raise DataError(
                f"{where}: column {col!r} row {pos[0]} is {_describe(a[tuple(pos)])}",
                source=where,
                column=col,
                row=int(pos[0]),
                value=float(a[tuple(pos)]),
                expected="a finite number",
            )


def _check_time_order(t: np.ndarray, where: str) -> None:
    """At least 2 samples, and time never going backwards (equal stamps are left to the repairs)."""
    N = t.size
    if N < 2:
        raise DataError(f"{where}: a log needs at least 2 samples; got {N}")
    refuse_time_going_back(t, where)


def refuse_time_going_back(t: np.ndarray, where: str) -> None:
    """A DataError naming the first row of ``t`` whose stamp lies before the previous one (and how many do)."""
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        r = int(back[0]) + 1
        raise DataError(
            f"{where}: time goes backwards at row {r}: t = {t[r]:.9g} s after {t[r - 1]:.9g} s "
            f"({back.size} such row(s))",
            source=where,
            column="t",
            row=r,
            value=float(t[r]),
            expected=f">= {t[r - 1]:.9g} s",
        )


def _drop_repeats(
    data: dict[str, np.ndarray], N: int, where: str, repair: bool, notes: list[str]
) -> dict[str, np.ndarray]:
    """``data`` without its exact repeats (every value but the time equals the previous row), said in ``notes``
    and a :class:`LogRepairWarning`; with ``repair=False`` a repeat is a DataError."""
    values = np.column_stack([data[k] for k in ("q", "dq", "tau", "ddq", "wrench") if k in data])
    repeat = np.r_[False, np.all(values[1:] == values[:-1], axis=1)]
    if not repeat.any():
        return data
    if not repair:
        r = int(np.argmax(repeat))
        raise DataError(
            f"{where}: row {r} repeats row {r - 1} exactly ({int(repeat.sum())} such rows); "
            "load with repair=True to drop them"
        )
    keep = ~repeat
    msg = (
        f"{where}: dropped {int(repeat.sum()):,} rows that exactly repeat the previous row (same q, dq, tau: "
        f"the host read one robot sample twice); {int(keep.sum()):,} of {N:,} rows remain"
    )
    warnings.warn(msg, LogRepairWarning, stacklevel=4)
    notes.append(msg)
    return {k: v[keep] for k, v in data.items()}


def _finish(
    data: dict[str, np.ndarray],
    where: str,
    n_joints: int | None,
    repair: bool,
    period: float | None,
    notes: tuple[str, ...] = (),
) -> RobotLog:
    """The log of ``data``: checked (shapes, finite values, absolute bounds, time order), then repaired (exact
    repeats dropped, irregular time re-timed or kept), each repair said in its notes after ``notes``."""
    t = np.asarray(data["t"], dtype=float).reshape(-1)
    _check_shapes(data, t.size, where, n_joints)
    _check_finite(data, where)
    check_absolute_bounds(where, t, {k: v for k, v in data.items() if k != "t"})
    _check_time_order(t, where)
    notes_out: list[str] = list(notes)
    data = _drop_repeats(data, t.size, where, repair, notes_out)
    data["t"] = _repair_time(data, where, repair, period, notes_out)
    log = RobotLog(
        t=data["t"],
        q=data["q"],
        dq=data["dq"],
        tau=data["tau"],
        ddq=data.get("ddq"),
        wrench=data.get("wrench"),
        source=where,
        notes=tuple(notes_out),
    )
    return log
