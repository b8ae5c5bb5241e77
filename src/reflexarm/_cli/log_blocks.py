"""Logs read in blocks by the commands that identify and validate: which logs are (``--block-rows``, their size,
their kind) and their scan, with the reader's notes printed as :func:`~reflexarm._cli.log_options.load_log_from_args`
prints them (:mod:`reflexarm.logs.blocks`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from reflexarm.errors import ConfigError

#: Table logs larger than this [bytes] are read in blocks unless ``--block-rows`` says otherwise (a 7-joint
#: CSV log holds about 300 bytes a row: 100 MB is some 3e5 rows, which take about 0.5 GB read whole).
STREAM_MIN_BYTES = 100 << 20


def scan_logs(args: argparse.Namespace, paths: list[str], robot: Any) -> list[Any] | None:
    """The logs at ``paths`` scanned for reading in blocks, or None to read them whole: ``--block-rows 0``, a log
    that is not a plain CSV/Parquet table, or (by default) logs below :data:`STREAM_MIN_BYTES`. The reader's
    notes are printed as :func:`load_log_from_args` prints them."""
    from reflexarm.logs.blocks import DEFAULT_BLOCK_ROWS, NotStreamable

    rows = getattr(args, "block_rows", None)
    if rows == 0:
        return None
    if rows is not None and rows < 0:
        raise ConfigError(f"--block-rows must be a positive number of rows (0: read whole); got {rows}")
    if rows is None and all(_size(p) < STREAM_MIN_BYTES for p in paths):
        return None
    block_rows = rows or DEFAULT_BLOCK_ROWS
    tables = []
    for p in paths:
        try:
            tables.append(_scan_log(args, p, robot, block_rows))
        except NotStreamable as e:
            print(f"log: {e}; all logs are read whole")
            return None
    args.block_rows = block_rows
    return tables


def _size(path: str) -> int:
    p = Path(path)
    return p.stat().st_size if p.is_file() else 0


def _scan_log(args: argparse.Namespace, path: str, robot: Any, block_rows: int) -> Any:
    """One log scanned (:func:`~reflexarm.logs.block_scan.scan_table`) with the log options of ``args``."""
    import warnings

    from reflexarm._cli.log_options import torque_source
    from reflexarm.logs import parse_column_mapping
    from reflexarm.logs.block_scan import scan_table

    torque_from, gains = torque_source(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        table = scan_table(
            path, joint_names=tuple(robot.joint_names), columns=parse_column_mapping(getattr(args, "columns", None)),
            time_unit=getattr(args, "time_unit", None), torque_from=torque_from, gains=gains, block_rows=block_rows,
        )  # fmt: skip
    cores = [str(w.message).split(": ", 1)[-1] for w in caught]
    for note in table.notes:
        print(("warning: " if any(c in note for c in cores) else "log: ") + note)
    for w, core in zip(caught, cores, strict=True):  # warnings that are not in the notes are passed on
        if not any(core in note for note in table.notes):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return table
