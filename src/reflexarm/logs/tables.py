"""Read a table log (CSV, Parquet) into arrays: columns found by :mod:`reflexarm.logs.columns`,
time stamps by :mod:`reflexarm.logs.timestamps`, joints of the JointState layout mapped row by row."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.columns import ColumnPlan, JointStateLayout, plan_columns
from reflexarm.logs.robot_log import _NUMERIC_KINDS, _describe, _refuse_dtype
from reflexarm.logs.timestamps import relative_seconds

__all__ = ["read_table"]


def read_table(
    p: Path,
    *,
    n_joints: int | None,
    joint_names: tuple[str, ...] | None,
    columns: dict[str, str] | None,
    time_unit: str | None,
    torque_from: str = "torque",
) -> tuple[dict[str, np.ndarray], list[str]]:
    """The log's arrays (``t`` in s from the first sample, ``q``, ``dq``, ``tau`` or, ``torque_from="current"``,
    ``current``, optional ``ddq``, ``wrench``; a mapping's scales applied) and the notes saying how they were
    found. A CSV file whose first row is all numbers has no header row: its columns are named by their
    position from 0 and must be mapped by position (``columns={"t": "0", "q": "1:7", ...}``)."""
    where = p.name
    suffix = p.suffix.lower()
    header = _csv_header(p, where) if suffix == ".csv" else ()
    df = _read_frame(p, where, suffix, header is None)
    notes: list[str] = []
    _name_columns(df, header, columns or {}, torque_from, where, notes)
    df, expanded = _expand_arrays(df)
    names = [str(c) for c in df.columns]
    plan = plan_columns(
        names, where=where, n_joints=n_joints, joint_names=joint_names, mapping=columns, torque_from=torque_from
    )
    notes += list(plan.notes)
    if expanded:
        notes.insert(
            0, f"{where}: array column(s) {', '.join(expanded)} expanded to one column per element (c.0, c.1, ..)"
        )
    keep = np.ones(len(df), dtype=bool)
    rows_of: np.ndarray | None = None
    if plan.layout is not None and plan.layout.names:
        assert plan.joint_names is not None
        rows_of, keep, note = _layout_rows(df, plan.layout, plan.joint_names, where)
        if note:
            notes.append(note)
    data: dict[str, np.ndarray] = {}
    raw_t = _time_stamps(df, plan, where)
    every = bool(keep.all())  # (no row left out: the arrays as read, without a copy of each)
    t, note = relative_seconds(
        raw_t if every else raw_t[keep], where=where, column=" + ".join(plan.time), unit=plan.time_unit or time_unit
    )
    if note:
        notes.append(note)
    data["t"] = t
    for s, cols in plan.joints.items():
        data[s] = _stack([_values(df, c, where) for c in cols], None if every else keep)
    if plan.layout is not None:
        kept = np.flatnonzero(keep)
        for s, cols in plan.layout.fields.items():
            arr = np.column_stack([_values(df, c, where, check=False) for c in cols])[keep]
            element = np.broadcast_to(np.arange(plan.n_joints), arr[:, : plan.n_joints].shape)
            if rows_of is not None:
                element = rows_of[keep]
            arr = np.take_along_axis(arr, element, axis=1)
            bad = ~np.isfinite(arr)
            if bad.any():
                r, j = (int(x) for x in np.argwhere(bad)[0])
                raise DataError(
                    f"{where}: column {cols[int(element[r, j])]!r} row {int(kept[r])} is {_describe(arr[r, j])} "
                    f"(joint {j + 1})",
                    source=where,
                    column=cols[int(element[r, j])],
                    row=int(kept[r]),
                    joint=plan.joint_names[j] if plan.joint_names else None,
                    value=float(arr[r, j]),
                    expected="a finite number",
                )
            data[s] = arr
    if plan.wrench is not None:
        data["wrench"] = _stack([_values(df, c, where) for c in plan.wrench], None if every else keep)
    for s, factor in plan.scale.items():
        if s in data:
            data[s] = data[s] * factor
    return data, notes


def _stack(columns: list[np.ndarray], rows: np.ndarray | None) -> np.ndarray:
    """The columns side by side (N, k), only ``rows`` (a mask) if given: one copy, column by column
    (np.column_stack copies row by row, 1.5x slower on a 900,000-row log)."""
    out = np.empty((columns[0].shape[0] if rows is None else int(rows.sum()), len(columns)))
    for k, c in enumerate(columns):
        out[:, k] = c if rows is None else c[rows]
    return out


def _name_columns(
    df: Any,
    header: list[str] | tuple[str, ...] | None,
    columns: dict[str, str],
    torque_from: str,
    where: str,
    notes: list[str],
) -> None:
    """Name ``df``'s columns: by position for a header-less file (whose signals must be mapped by position),
    else as the file's header writes them (a name given twice is refused, naming it and its positions)."""
    if header is None:
        df.columns = [str(k) for k in range(df.shape[1])]
        _refuse_unmapped_headerless(columns, torque_from, df.shape[1], where)
        notes.append(
            f"{where}: no header row (the first row is numbers): columns named by position 0..{df.shape[1] - 1}"
        )
    else:
        names = [str(c).strip() for c in df.columns]
        if header and len(header) == len(names):
            names = list(header)  # pandas renames repeated names (q_1, q_1.1): the file's own names
        dup = sorted({c for c in names if names.count(c) > 1})
        if dup:
            at = [k for k, c in enumerate(names) if c == dup[0]]
            raise DataError(
                f"{where}: column {dup[0]!r} appears {len(at)} times (positions {', '.join(map(str, at))}, from 0)"
                + (f"; also repeated: {', '.join(map(repr, dup[1:]))}" if dup[1:] else "")
                + "; every column needs its own name: rename the copies",
                source=where,
                column=dup[0],
                value=tuple(at),
            )
        df.columns = names


def _csv_header(p: Path, where: str) -> list[str] | None:
    """The CSV file's header row as written (repeated names kept), or None if its first row is all numbers."""
    import csv

    try:
        with p.open(newline="", encoding="utf-8-sig", errors="replace") as fh:
            row = next(csv.reader(fh), None)
    except (OSError, csv.Error) as e:
        raise DataError(f"{where}: cannot read the file as csv: {e}") from e
    if row is None:
        raise DataError(f"{where}: the file is empty")
    cells = [c.strip() for c in row]
    if any(cells) and all(_is_number(c) for c in cells if c):
        return None
    return cells


def _read_frame(p: Path, where: str, suffix: str, headerless: bool) -> Any:
    import pandas as pd

    try:
        if suffix == ".csv":
            return pd.read_csv(p, header=None) if headerless else pd.read_csv(p)
        import pyarrow.parquet as pq

        # (what pd.read_parquet does, each column in a block of its own: no copy of the whole table into one)
        return pq.read_table(p).to_pandas(split_blocks=True, self_destruct=True)
    except Exception as e:  # pandas/pyarrow raise many types; explain and chain
        raise DataError(f"{where}: cannot read the file as {suffix[1:]}: {e}") from e


def _refuse_unmapped_headerless(columns: dict[str, str], torque_from: str, width: int, where: str) -> None:
    """A header-less file's signals must all be mapped by position (nothing can be found by name)."""
    from reflexarm.logs.column_mapping import parse_column_spec

    torque = "current" if torque_from == "current" else "tau"
    missing = [k for k in ("t", "q", "dq", torque) if k not in columns]
    named = [k for k, v in columns.items() if parse_column_spec(k, v).positions is None]
    if missing or named:
        n = max((width - 1) // 3, 1)
        example = (
            f"t=0,q=1:{1 + n},dq={1 + n}:{1 + 2 * n},{'cur' if torque == 'current' else 'tau'}={1 + 2 * n}:{1 + 3 * n}"
        )
        problem = (
            f"no position given for {', '.join(missing)}"
            if missing
            else f"{', '.join(named)} named by column name, which a header-less file has not"
        )
        raise DataError(
            f"{where}: no header row (the first row is numbers, {width} columns): name the columns by position, "
            f"0-based with the end excluded, e.g. --columns {example}; {problem}",
            source=where,
            column=tuple(missing or named),
        )


def _expand_arrays(df: Any) -> tuple[Any, list[str]]:
    """Columns whose cells are arrays (Parquet lists, e.g. a JointState's ``name`` / ``position`` as a
    bag-to-dataframe export stores them) become one column per element, ``c.0``, ``c.1``, ..."""
    import pandas as pd

    expanded = []
    parts = []
    for c in df.columns:
        col = df[c]
        first = col.iloc[0] if len(col) else None
        if str(col.dtype) == "object" and isinstance(first, (list, tuple, np.ndarray)):
            width = max((len(v) for v in col if isinstance(v, (list, tuple, np.ndarray))), default=0)
            text = any(isinstance(x, str) for v in col[:100] if isinstance(v, (list, tuple, np.ndarray)) for x in v)
            pad: object = "" if text else np.nan
            cells = [
                list(v) + [pad] * (width - len(v)) if isinstance(v, (list, tuple, np.ndarray)) else [pad] * width
                for v in col
            ]
            parts.append(pd.DataFrame(cells, columns=[f"{c}.{k}" for k in range(width)], index=df.index))
            expanded.append(str(c))
        else:
            parts.append(col.to_frame())
    return (pd.concat(parts, axis=1) if expanded else df), expanded


def _time_stamps(df: Any, plan: ColumnPlan, where: str) -> np.ndarray:
    if len(plan.time) == 2:
        sec, nsec = (_integers(df, c, where) for c in plan.time)
        return sec * np.int64(1_000_000_000) + nsec
    c = plan.time[0]
    col = df[c]
    kind = str(getattr(col.dtype, "kind", "O"))
    if kind in "iu":
        return np.asarray(col.to_numpy(), dtype=np.int64)
    return _values(df, c, where)


def _integers(df: Any, c: str, where: str) -> np.ndarray:
    col = df[c]
    if str(getattr(col.dtype, "kind", "O")) not in "iu":
        raise DataError(f"{where}: column {c!r} has dtype {col.dtype}; header stamp seconds/nanoseconds are integers")
    return np.asarray(col.to_numpy(), dtype=np.int64)


def _values(df: Any, c: str, where: str, check: bool = True) -> np.ndarray:
    """Column ``c`` as float64, refusing text and booleans, and (``check``) non-finite values by row."""
    col = df[c]
    kind = str(getattr(col.dtype, "kind", "O"))
    if kind not in _NUMERIC_KINDS:
        bad = next((i for i, v in enumerate(col.tolist()) if not _is_number(v)), None)
        if not check and kind == "O" and bad is None:  # numbers with gaps (NaN) read as objects
            return np.asarray(col.to_numpy(dtype=float, na_value=np.nan), dtype=float)
        if kind in "OUS" and bad is not None:
            raise DataError(
                f"{where}: column {c!r} row {bad}: {col.iloc[bad]!r} is not a number",
                source=where,
                column=c,
                row=bad,
                value=col.iloc[bad],
                expected="a number",
            )
        raise _refuse_dtype(where, f"column {c!r}", col.dtype, kind)
    values = np.asarray(col.to_numpy(dtype=float, na_value=np.nan), dtype=float)
    bad_cells = ~np.isfinite(values)
    if check and bad_cells.any():
        r = int(np.argmax(bad_cells))
        raise DataError(
            f"{where}: column {c!r} row {r} is {_describe(values[r])}",
            source=where,
            column=c,
            row=r,
            value=float(values[r]),
            expected="a finite number",
        )
    return values


def _is_number(v: object) -> bool:
    try:
        float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def _layout_rows(
    df: Any, layout: JointStateLayout, joint_names: tuple[str, ...], where: str
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Per row, the array element of each model joint (N, n); the rows that hold the arm; a note."""
    import pandas as pd

    names = df[list(layout.names)].astype(object).where(pd.notna(df[list(layout.names)]), "")
    tuples = list(map(tuple, names.astype(str).to_numpy().tolist()))
    n, N = len(joint_names), len(tuples)
    elements = np.zeros((N, n), dtype=np.int64)
    keep = np.zeros(N, dtype=bool)
    other: dict[str, int] = {}
    lookup: dict[tuple[str, ...], np.ndarray | None] = {}
    for r, tup in enumerate(tuples):
        if tup not in lookup:
            position = {name: k for k, name in enumerate(tup) if name}
            have = [j for j in range(n) if joint_names[j] in position]
            if not have:
                lookup[tup] = None
            elif len(have) < n:
                missing = [joint_names[j] for j in range(n) if j not in have]
                raise DataError(
                    f"{where}: row {r} names joints {', '.join(x for x in tup if x)}: the arm's joint(s) "
                    f"{', '.join(map(repr, missing))} missing (a row must hold all of the arm's joints or none)",
                    source=where,
                    row=r,
                    joint=missing[0],
                    value=tuple(x for x in tup if x),
                    expected=joint_names,
                )
            else:
                lookup[tup] = np.array([position[name] for name in joint_names])
        found = lookup[tup]
        if found is None:
            for x in tup:
                if x:
                    other[x] = other.get(x, 0) + 1
            continue
        elements[r] = found
        keep[r] = True
    if not keep.any():
        raise DataError(
            f"{where}: no row names the arm's joints ({', '.join(joint_names)}); names found: {', '.join(other)}"
        )
    orders = len({tup for tup, v in lookup.items() if v is not None})
    parts = []
    if orders > 1:
        parts.append(f"the joint order changes between rows ({orders} orders), mapped per row")
    if other:
        parts.append(
            f"left out {int((~keep).sum()):,} row(s) that hold none of the arm's joints (joints "
            f"{', '.join(other)}: not in the arm)"
        )
    return elements, keep, (f"{where}: JointState rows: " + "; ".join(parts)) if parts else None
