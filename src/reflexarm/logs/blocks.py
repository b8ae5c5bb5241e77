"""Read a table log (CSV, Parquet) in blocks of rows: the pipeline of :func:`~reflexarm.logs.load_log` and
:func:`~reflexarm.logs.preprocess_log` with memory bounded by the block, not by the log.

Two passes over the file:

1. **scan** (:func:`~reflexarm.logs.block_scan.scan_table`): the time stamps (8 bytes a row, the only
   whole-log array kept) and the exact repeats (a row equal to the previous one, compared across block
   edges). Then, on the whole time vector, what :func:`~reflexarm.logs.load_log` does with it: the unit and the origin
   (:func:`~reflexarm.logs.timestamps.relative_seconds`), time going backwards, the repeats dropped, the
   period and the irregular steps. A log whose stamps need re-timing (jitter) is not streamed
   (:class:`NotStreamable`): re-timing compares positions and velocities over the whole log.
2. **read** (:meth:`StreamedTable.blocks`): the values, block by block, with the checks
   :class:`~reflexarm.logs.RobotLog` makes (finite values, :data:`~reflexarm.logs.bounds.ABSOLUTE_BOUNDS`),
   reporting rows of the whole file.

Preprocessing (:func:`preprocessed_blocks`) follows the plan :func:`~reflexarm.logs.preprocessing.plan_preprocessing`
makes from the time stamps alone; each block of the grid is computed on a window that extends it by
:func:`window_overlap` samples on each side within its segment, and only the block is kept. The zero-phase
filter started on a window differs from the one run over the whole segment by its start transient, which
decays like ``r^m`` after m samples (r: the largest pole magnitude of the Butterworth filter, 0.976 at 10 Hz
and 1 kHz); the overlap makes ``r^m`` below :data:`OVERLAP_DECAY` (1e-20: 1,917 samples there). The
not-a-knot cubic spline's end effect decays faster, by 2 - sqrt(3) = 0.27 a sample. Block edges that are
segment edges (the log's start and end, a long gap) are the segment's own: the padding there is that of the
whole log. What is left is rounding: ``filtfilt`` with the filter's (b, a) carries a rounding noise of about
1e-10 relative at fc / fs = 0.02 (its distance to the second-order-sections filter), and a window started
elsewhere reproduces the whole log's rounding only to that level (measured: 3e-11 of each column's largest
value on q, 2.4e-10 on ddq; tests/test_ident_streaming.py).

Only plain tables stream: columns found by name or position (the schema, joint-named columns, a mapping);
the JointState layout and array columns are read whole (:class:`NotStreamable` says why).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.preprocessing import PreprocessingPlan, Segment, preprocess_window
from reflexarm.logs.robot_log import WRENCH_COLUMNS, RobotLog

__all__ = [
    "DEFAULT_BLOCK_ROWS",
    "OVERLAP_DECAY",
    "NotStreamable",
    "StreamedTable",
    "preprocessed_blocks",
    "window_overlap",
]

#: Rows per block: a 7-joint log costs about 2 kB of peak memory a block row (the table, its arrays, the window and
#: the filter's copies), ~200 MB a block; the overlap (2 x 1,917 samples at 10 Hz / 1 kHz) adds 4 % to the filtering.
DEFAULT_BLOCK_ROWS = 100_000
#: The filter's start transient on a window decays to this fraction over the overlap (see the module docstring).
OVERLAP_DECAY = 1e-20
#: Overlap without a filter: the cubic spline's end effect (0.27 a sample) is 1e-36 after this many samples.
_SPLINE_OVERLAP = 64
#: Bytes of CSV text pyarrow parses at a time (its batches are then joined into blocks of rows). Its streaming reader
#: reads some 30 of these ahead: 16 MB held a 476 MB file whole (pool peak 474 MB), 1 MB holds 39 MB.
_CSV_BLOCK_BYTES = 1 << 20


class NotStreamable(Exception):  # noqa: N818 (a reason to read whole, not an error of the log)
    """The log cannot be read in blocks (its message says why); read it whole with :func:`load_log`."""


@dataclass(frozen=True)
class _Columns:
    """The file's columns of each signal (positions in the file) and the factors a mapping gives them."""

    time: tuple[int, ...]
    joints: dict[str, tuple[int, ...]]
    wrench: tuple[int, ...] | None
    names: tuple[str, ...]
    scale: dict[str, float]


class StreamedTable:
    """A table log read in blocks (see the module docstring); made by :func:`scan_table`.

    Attributes:
        source: the file's name; t: the log's time [s] (relative, repeats dropped); notes: what loading
        did (as :func:`~reflexarm.logs.load_log`'s notes); n: joints; has_ddq, has_wrench: optional signals.
    """

    def __init__(self, path: Path, cols: _Columns, headerless: bool, torque_from: str, gains: Any) -> None:
        self.path = path
        self.source = path.name
        self._cols = cols
        self._headerless = headerless
        self._torque_from = torque_from
        self._gains = gains
        self.n = len(cols.joints["q"])
        self.has_ddq = "ddq" in cols.joints
        self.has_wrench = cols.wrench is not None
        self.t = np.zeros(0)
        self.keep: np.ndarray | None = None  # rows kept (None: all)
        self.notes: tuple[str, ...] = ()
        self.time_column = ""
        self.time_unit: str | None = None

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def period(self) -> float:
        return float(np.median(np.diff(self.t)))

    def _tables(self, block_rows: int) -> Iterator[tuple[int, Any]]:
        """(first file row, pyarrow table of at most ``block_rows`` rows) over the file."""
        batches = _batches(self.path, self._headerless, len(self._cols.names))
        row, pending, size = 0, [], 0
        for batch in batches:
            pending.append(_as_table(batch))
            size += batch.num_rows
            while size >= block_rows:
                table = _table(pending)
                yield row, table.slice(0, block_rows)
                rest = table.slice(block_rows)
                pending, size, row = [rest], rest.num_rows, row + block_rows
        if size:
            yield row, _table(pending)

    def raw_time(self, block_rows: int) -> Iterator[np.ndarray]:
        """The time stamps as stored (integers or floats), block by block."""
        for _, table in self._tables(block_rows):
            yield _time_stamps(table, self._cols, self.source)

    def values(self, block_rows: int) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        """(first file row, {q, dq, tau, ddq, wrench}) per block of the file, float64, a mapping's scales applied
        and motor currents turned into torques."""
        for row, table in self._tables(block_rows):
            data = self._data(table, row)
            if self._torque_from == "current":
                data["tau"] = data.pop("current") * self._gains
            yield row, data

    def time_and_values(self, block_rows: int) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
        """(time stamps as stored, values as :meth:`values` but motor currents kept as ``current``) per block."""
        for row, table in self._tables(block_rows):
            yield _time_stamps(table, self._cols, self.source), self._data(table, row)

    def _data(self, table: Any, row: int) -> dict[str, np.ndarray]:
        names = self._cols.names
        data = {s: _matrix(table, cols, names, row, self.source) for s, cols in self._cols.joints.items()}
        if self._cols.wrench is not None:
            data["wrench"] = _matrix(table, self._cols.wrench, names, row, self.source)
        for s, factor in self._cols.scale.items():
            if s in data:
                data[s] = data[s] * factor
        return data

    def blocks(self, block_rows: int = DEFAULT_BLOCK_ROWS) -> Iterator[tuple[int, RobotLog]]:
        """(first row of the log, the log's rows from there as a :class:`RobotLog`), repeats dropped."""
        start = 0
        for row, data in self.values(block_rows):
            m = data["q"].shape[0]
            rows = np.arange(row, row + m)
            if self.keep is not None:
                keep = self.keep[row : row + m]
                data = {k: v[keep] for k, v in data.items()}
                rows = rows[keep]
            t = self.t[start : start + rows.size]
            with shifted_rows(rows):
                _check_values(self.source, rows, data)
                if t.size:
                    block = _block_log(self.source, t, data)
            if t.size:
                yield start, block
            start += t.size


def window_overlap(plan: PreprocessingPlan) -> int:
    """Grid samples a block's window extends beyond it on each side (see the module docstring)."""
    if plan.filt is None:
        return _SPLINE_OVERLAP
    r = float(np.max(np.abs(np.roots(plan.filt[1]))))
    return max(int(math.ceil(math.log(OVERLAP_DECAY) / math.log(r))), plan.filt[2], _SPLINE_OVERLAP)


def preprocessed_blocks(
    table: StreamedTable,
    plan: PreprocessingPlan,
    block_rows: int = DEFAULT_BLOCK_ROWS,
    raw_hook: Callable[[int, RobotLog], None] | None = None,
) -> Iterator[RobotLog]:
    """The preprocessed log (as :func:`~reflexarm.logs.preprocess_log` with ``plan``) in blocks of at most
    ``block_rows`` grid samples, in order; ``raw_hook(first_row, block)`` sees each block of the raw log once."""
    if block_rows < 1:
        raise DataError(f"{table.source}: blocks need at least one row; got block_rows = {block_rows}")
    ov = window_overlap(plan)
    rows = _RowBuffer(table.blocks(block_rows), raw_hook)
    for seg in plan.segments:
        t_seg = table.t[seg.i0 : seg.i1]
        for c0 in range(0, seg.k, block_rows):
            c1 = min(c0 + block_rows, seg.k)
            w0, w1 = max(c0 - ov, 0), min(c1 + ov, seg.k)
            r0, r1 = _raw_rows(plan, seg, t_seg, w0, w1)
            window = rows.take(seg.i0 + r0, seg.i0 + r1)
            t, q, dq, tau, ddq, wrench, tau_raw = (
                None if a is None else a[c0 - w0 : c1 - w0] for a in preprocess_window(window, plan, seg, w0, w1)
            )
            assert t is not None and q is not None and dq is not None and tau is not None
            yield RobotLog(
                t=t, q=q, dq=dq, tau=tau, ddq=ddq, wrench=wrench,
                tau_raw=tau_raw if plan.keeps_raw_torque else None, source=table.source,
            )  # fmt: skip
    rows.finish()


def _raw_rows(plan: PreprocessingPlan, seg: Segment, t_seg: np.ndarray, w0: int, w1: int) -> tuple[int, int]:
    """The segment's samples ``[r0, r1)`` a window of grid samples ``[w0, w1)`` is computed from."""
    if not plan.resample:
        return w0, w1
    lo = int(np.searchsorted(t_seg, seg.t0 + seg.period * w0, side="right")) - 3
    hi = int(np.searchsorted(t_seg, seg.t0 + seg.period * (w1 - 1), side="left")) + 3
    return max(lo, 0), min(hi, t_seg.size)


class _RowBuffer:
    """Rows ``[r0, r1)`` of a log read in blocks, for windows that move forward (blocks behind are dropped)."""

    def __init__(self, blocks: Iterator[tuple[int, RobotLog]], hook: Callable[[int, RobotLog], None] | None) -> None:
        self._blocks = blocks
        self._hook = hook
        self._held: list[tuple[int, RobotLog]] = []

    def finish(self) -> None:
        """Read the blocks no window needed (samples after the last kept segment), for the hook."""
        for start, block in self._blocks:
            if self._hook is not None:
                self._hook(start, block)

    def take(self, r0: int, r1: int) -> RobotLog:
        self._held = [(s, b) for s, b in self._held if s + len(b) > r0]
        while not self._held or self._held[-1][0] + len(self._held[-1][1]) < r1:
            start, block = next(self._blocks)
            if self._hook is not None:
                self._hook(start, block)
            self._held.append((start, block))
        parts = [b.select(slice(max(r0 - s, 0), min(r1 - s, len(b)))) for s, b in self._held if s < r1]
        if len(parts) == 1:
            return parts[0]

        def cat(name: str) -> np.ndarray | None:
            arrays = [getattr(p, name) for p in parts]
            return None if arrays[0] is None else np.concatenate(arrays)

        return RobotLog(
            t=cat("t"), q=cat("q"), dq=cat("dq"), tau=cat("tau"), ddq=cat("ddq"), wrench=cat("wrench"),  # type: ignore[arg-type]
            source=parts[0].source,
        )  # fmt: skip


def _block_log(source: str, t: np.ndarray, data: dict[str, np.ndarray]) -> RobotLog:
    return RobotLog(
        t=t, q=data["q"], dq=data["dq"], tau=data["tau"], ddq=data.get("ddq"), wrench=data.get("wrench"),
        source=source,
    )  # fmt: skip


def _check_values(source: str, rows: np.ndarray, data: dict[str, np.ndarray]) -> None:
    """Finite values (as :func:`~reflexarm.logs.load_log` checks them), named by the file's ``rows``."""
    from reflexarm.logs.robot_log import _describe

    for k, a in data.items():
        bad = ~np.isfinite(a)
        if bad.any():
            r, c = (int(x) for x in np.argwhere(bad)[0])
            col = WRENCH_COLUMNS[c] if k == "wrench" else f"{k}_{c + 1}"
            raise DataError(
                f"{source}: column {col!r} row {int(rows[r])} is {_describe(a[r, c])}",
                source=source, column=col, row=int(rows[r]), value=float(a[r, c]), expected="a finite number",
            )  # fmt: skip


@contextmanager
def shifted_rows(rows: np.ndarray) -> Iterator[None]:
    """Plausibility errors raised on a block (rows from 0) name the log's ``rows`` instead."""
    from reflexarm.errors import ImplausibleDataError

    try:
        yield
    except ImplausibleDataError as e:
        msg, samples = str(e), []
        for s in e.samples:
            moved = s._replace(row=int(rows[s.row]))  # type: ignore[attr-defined]
            msg = msg.replace(str(s), str(moved), 1)
            samples.append(moved)
        raise ImplausibleDataError(msg, tuple(samples)) from None


# the pyarrow side: batches of a CSV / Parquet file, columns as numbers
def _batches(path: Path, headerless: bool, width: int) -> Iterator[Any]:
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    try:
        if path.suffix.lower() == ".csv":
            yield from pacsv.open_csv(
                path,
                read_options=pacsv.ReadOptions(
                    column_names=[f"c{k}" for k in range(width)],
                    skip_rows=0 if headerless else 1,
                    block_size=_CSV_BLOCK_BYTES,
                ),
            )
        else:
            with pq.ParquetFile(path, pre_buffer=False) as f:  # pre-buffering holds the whole file
                yield from f.iter_batches(batch_size=65_536)
    except Exception as e:  # pyarrow raises many types; explain and chain
        raise DataError(f"{path.name}: cannot read the file as {path.suffix[1:]} in blocks: {e}") from e


def _as_table(batch: Any) -> Any:
    import pyarrow as pa

    return pa.Table.from_batches([batch])


def _table(tables: list[Any]) -> Any:
    import pyarrow as pa

    return tables[0] if len(tables) == 1 else pa.concat_tables(tables)


def _matrix(table: Any, cols: tuple[int, ...], names: tuple[str, ...], row: int, where: str) -> np.ndarray:
    import pyarrow.types as pat

    out = np.empty((table.num_rows, len(cols)))
    for j, k in enumerate(cols):
        col = table.column(k)
        if not (pat.is_integer(col.type) or pat.is_floating(col.type) or pat.is_null(col.type)):
            raise NotStreamable(f"{where}: column {names[k]!r} is {col.type} from row {row} on, not numbers")
        out[:, j] = col.to_numpy(zero_copy_only=False)
    return out


def _time_stamps(table: Any, cols: _Columns, where: str) -> np.ndarray:
    import pyarrow.types as pat

    parts = [table.column(k) for k in cols.time]
    if len(parts) == 2:
        if not all(pat.is_integer(p.type) for p in parts):
            raise NotStreamable(f"{where}: header stamp seconds/nanoseconds are not integers")
        sec, nsec = (np.asarray(p.to_numpy(), dtype=np.int64) for p in parts)
        return sec * np.int64(1_000_000_000) + nsec
    c = parts[0]
    if pat.is_integer(c.type):
        return np.asarray(c.to_numpy(), dtype=np.int64)
    if not pat.is_floating(c.type):
        raise NotStreamable(f"{where}: the time column is {c.type}, not numbers")
    return np.asarray(c.to_numpy(zero_copy_only=False), dtype=float)
