"""Robot log files: load and save CSV / Parquet / npz in the documented schema.

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

Loading validates and repairs as :class:`~reflexarm.ident.robot_log.RobotLog` does (see
:mod:`reflexarm.ident.robot_log`).
"""

from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from reflexarm.errors import DataError
from reflexarm.ident.robot_log import (
    _NUMERIC_KINDS,
    WRENCH_COLUMNS,
    RobotLog,
    _describe,
    _finish,
    _numeric,
    _refuse_dtype,
)

__all__ = ["load_log", "save_log"]

_JOINT_GROUPS = ("q", "dq", "tau", "ddq")
_COL_RE = re.compile(r"^(q|dq|ddq|tau)_(\d+)$")


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
