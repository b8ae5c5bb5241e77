"""The first pass over a table log read in blocks (:mod:`reflexarm.logs.blocks`): its columns planned from the
header (as :func:`~reflexarm.logs.tables.read_table` plans them), then its time stamps and exact repeats
scanned and held to what :func:`~reflexarm.logs.load_log` does with them (the same notes, warnings and
errors)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.blocks import DEFAULT_BLOCK_ROWS, NotStreamable, StreamedTable, _Columns
from reflexarm.logs.robot_log import LogRepairWarning, refuse_time_going_back

__all__ = ["scan_table"]


def scan_table(
    path: str | Path,
    *,
    joint_names: tuple[str, ...],
    columns: dict[str, str] | None = None,
    time_unit: str | None = None,
    torque_from: str = "torque",
    gains: Any = None,
    block_rows: int = DEFAULT_BLOCK_ROWS,
) -> StreamedTable:
    """Plan the columns and scan the time stamps and repeats of a CSV / Parquet log (arguments as
    :func:`~reflexarm.logs.load_log`); :class:`~reflexarm.logs.blocks.NotStreamable` if it must be read whole."""
    table = open_table(Path(path), joint_names, columns, time_unit, torque_from, gains)
    scan_time(table, time_unit, block_rows)
    return table


def open_table(
    p: Path,
    joint_names: tuple[str, ...],
    columns: dict[str, str] | None,
    time_unit: str | None,
    torque_from: str,
    gains: Any,
) -> StreamedTable:
    """The table's columns found from its header (nothing read beyond the first rows)."""
    import pandas as pd

    from reflexarm.logs.columns import plan_columns
    from reflexarm.logs.files import _check_torque_source
    from reflexarm.logs.motor_current import check_gains
    from reflexarm.logs.tables import _csv_header, _name_columns

    where, suffix = p.name, p.suffix.lower()
    if suffix not in (".csv", ".parquet", ".pq") or not p.is_file():
        raise NotStreamable(f"{where}: only CSV and Parquet files are read in blocks")
    _check_torque_source(torque_from, gains, len(joint_names), where)
    header: list[str] | tuple[str, ...] | None = ()
    if suffix == ".csv":
        header = _csv_header(p, where)
        try:
            head = pd.read_csv(p, nrows=5, header=None if header is None else "infer")
        except Exception as e:  # pandas raises many types; explain and chain
            raise DataError(f"{where}: cannot read the file as csv: {e}") from e
    else:
        head = _parquet_head(p, where)
    notes: list[str] = []
    _name_columns(head, header, columns or {}, torque_from, where, notes)
    names = [str(c) for c in head.columns]
    plan = plan_columns(
        names, where=where, n_joints=len(joint_names), joint_names=joint_names, mapping=columns, torque_from=torque_from
    )
    if plan.layout is not None:
        raise NotStreamable(f"{where}: a JointState layout (arrays of joints per row) is read whole")
    notes += list(plan.notes)
    pos = {c: k for k, c in enumerate(names)}
    cols = _Columns(
        time=tuple(pos[c] for c in plan.time),
        joints={s: tuple(pos[c] for c in cs) for s, cs in plan.joints.items()},
        wrench=None if plan.wrench is None else tuple(pos[c] for c in plan.wrench),
        names=tuple(names),
        scale=dict(plan.scale),
    )
    k = check_gains(gains, len(joint_names), where) if torque_from == "current" else None
    table = StreamedTable(p, cols, header is None, torque_from, k)
    table.notes = tuple(notes)
    table.time_column = " + ".join(plan.time)
    table.time_unit = plan.time_unit or time_unit
    return table


def _parquet_head(p: Path, where: str) -> Any:
    import pandas as pd
    import pyarrow.parquet as pq
    import pyarrow.types as pat

    try:
        schema = pq.read_schema(p)
    except Exception as e:  # pyarrow raises many types; explain and chain
        raise DataError(f"{where}: cannot read the file as parquet: {e}") from e
    nested = [f.name for f in schema if pat.is_nested(f.type)]
    if nested:
        raise NotStreamable(f"{where}: array column(s) {', '.join(nested)} are read whole")
    return pd.DataFrame(columns=list(schema.names))


def scan_time(table: StreamedTable, time_unit: str | None, block_rows: int = DEFAULT_BLOCK_ROWS) -> None:
    """Pass 1: the time stamps made relative (unit, origin), repeats found and dropped, the steps checked; sets
    ``table.t``, ``table.keep`` and ``table.notes``. :class:`NotStreamable` when the stamps need re-timing."""
    from reflexarm.logs.timestamps import relative_seconds

    where = table.source
    raw, repeat, current_max = _scan(table, block_rows)
    notes = list(table.notes)
    t, note = relative_seconds(raw, where=where, column=table.time_column, unit=table.time_unit)
    del raw
    if note:
        notes.append(note)
    if table._torque_from == "current":
        k = table._gains
        notes.append(
            f"{where}: measured torque = gain x motor current, gains {', '.join(f'{g:g}' for g in k)} Nm/A "
            f"(|current| up to {current_max[0]:.4g} A -> |torque| up to {current_max[1]:.4g} Nm)"
        )
    N = t.size
    if N < 2:
        raise DataError(f"{where}: a log needs at least 2 samples; got {N}")
    refuse_time_going_back(t, where)
    if repeat.any():
        keep = ~repeat
        t = t[keep]
        msg = (
            f"{where}: dropped {int(repeat.sum()):,} rows that exactly repeat the previous row (same q, dq, tau: "
            f"the host read one robot sample twice); {int(keep.sum()):,} of {N:,} rows remain"
        )
        warnings.warn(msg, LogRepairWarning, stacklevel=4)
        notes.append(msg)
        table.keep = keep
    _refuse_irregular(t, where)
    table.t, table.notes = t, tuple(notes)


def _scan(table: StreamedTable, block_rows: int) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """(the stamps as stored, the rows that repeat the previous row exactly, max |current| and |torque|)."""
    stamps, repeats = [], []
    last: np.ndarray | None = None
    cmax = tmax = 0.0
    for raw, data in table.time_and_values(block_rows):
        if "current" in data:
            current = data.pop("current")
            cmax = max(cmax, float(np.max(np.abs(current), initial=0.0)))
            data["tau"] = current * table._gains
            tmax = max(tmax, float(np.max(np.abs(data["tau"]), initial=0.0)))
        values = np.column_stack([data[k] for k in ("q", "dq", "tau", "ddq", "wrench") if k in data])
        prev = np.vstack([values[:1] if last is None else last, values[:-1]])
        rep = np.all(values == prev, axis=1)
        if last is None:
            rep[0] = False
        stamps.append(raw)
        repeats.append(rep)
        last = values[-1:]
    if not stamps:
        raise DataError(f"{table.source}: the file has no rows")
    return np.concatenate(stamps), np.concatenate(repeats), (cmax, tmax)


def _refuse_irregular(t: np.ndarray, where: str) -> None:
    """Steps that are not whole periods need re-timing, which needs the whole log: not streamed."""
    from reflexarm.logs._retime import irregular_steps

    steps = np.diff(t)
    if not np.any(steps > 0):
        raise DataError(f"{where}: all time stamps are equal")
    T = float(np.median(steps[steps > 0]))
    irregular = irregular_steps(steps, T)
    if irregular.any():
        raise NotStreamable(
            f"{where}: {int(irregular.sum()):,} time steps are not whole periods of {T * 1e3:.4g} ms (jitter, repeated "
            "stamps): re-timing compares positions and velocities over the whole log, so it is read whole"
        )
