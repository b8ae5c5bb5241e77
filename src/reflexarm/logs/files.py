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

Logs as robots export them load too (:func:`load_log`): columns named after the joints, the ROS 2
JointState layout, numbered from 0, or named by a column mapping (:mod:`reflexarm.logs.columns`;
other columns are left out with a note); time stamps in s, ms, us or ns, from any origin (the Unix
epoch included), always made relative to the log's first sample (:mod:`reflexarm.logs.timestamps`);
rosbag2 and MCAP bags (:mod:`reflexarm.logs.bags`). :func:`save_log` writes the schema.

Loading validates and repairs as :class:`~reflexarm.logs.robot_log.RobotLog` does (see
:mod:`reflexarm.logs.robot_log`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError, DataError
from reflexarm.logs.bags import BAG_SUFFIXES, read_bag
from reflexarm.logs.columns import TORQUE_SOURCES
from reflexarm.logs.motor_current import check_gains, torque_from_current
from reflexarm.logs.robot_log import RobotLog, _finish, _numeric
from reflexarm.logs.tables import read_table
from reflexarm.logs.timestamps import relative_seconds

__all__ = ["load_log", "save_log"]


def load_log(
    path: str | os.PathLike[str],
    *,
    n_joints: int | None = None,
    joint_names: Sequence[str] | None = None,
    columns: Mapping[str, str] | None = None,
    time_unit: str | None = None,
    joint_topic: str | None = None,
    wrench_topic: str | None = None,
    repair: bool = True,
    period: float | None = None,
    torque_from: str = "torque",
    gains: npt.ArrayLike | None = None,
) -> RobotLog:
    """Load a log: ``.csv``, ``.parquet``, ``.npz`` (schema in the module docstring) or a ROS 2 bag.

    Tables may also name their columns after the joints or hold the ROS 2 JointState layout (see
    :mod:`reflexarm.logs.columns`); bags (a rosbag2 folder, a ``.db3`` or ``.mcap`` file) are read
    by :mod:`reflexarm.logs.bags`. Times are made relative to the first sample and converted to
    seconds (:mod:`reflexarm.logs.timestamps`). What was recognized, converted, left out or repaired
    is listed in the returned log's ``notes``.

    Args:
        path: the file (or the bag's folder).
        n_joints: the robot's joint count (e.g. ``robot.n``); a log with another count is rejected.
        joint_names: the robot's joint names in the model's order (e.g. ``robot.joint_names``): maps
            joint-named columns and bag messages by name; implies ``n_joints``.
        columns: explicit column mapping, e.g. ``{"q": "position_{joint}", "t": "stamp_ns"}`` (see
            :mod:`reflexarm.logs.columns`); tables only.
        time_unit: ``"s"``, ``"ms"``, ``"us"`` or ``"ns"`` (default: from the column name, else inferred).
        joint_topic: the bag's ``sensor_msgs/msg/JointState`` topic (default: the only one).
        wrench_topic: the bag's ``geometry_msgs/msg/WrenchStamped`` topic of the wrist sensor, if any.
        repair: drop exact repeats and re-time jittery time stamps (with a warning); if False such
            logs raise :class:`DataError`.
        period: nominal sample period [s] for re-timing (default: the median step).
        torque_from: ``"torque"`` (the log's torque columns / effort field) or ``"current"``: the measured
            torque is ``gains`` times the log's motor currents (:mod:`reflexarm.logs.motor_current`;
            tables: mapping key ``current`` or columns ``current_1..n``, ``current_<joint>``; bags: the
            JointState effort field; npz: an array ``current`` instead of ``tau``).
        gains: with ``torque_from="current"``, one gain per joint [Nm/A] in the model's joint order.

    Raises:
        DataError: unreadable file, missing columns, wrong joint count, NaN/inf, time going
            backwards; the message names the file, the column or row and the problem.
    """
    p = Path(path)
    where = p.name
    names = None if joint_names is None else tuple(joint_names)
    if names is not None:
        if n_joints is not None and n_joints != len(names):
            raise DataError(f"{where}: n_joints {n_joints} but {len(names)} joint names given")
        n_joints = len(names)
    suffix = p.suffix.lower()
    bag = p.is_dir() or suffix in BAG_SUFFIXES
    if not p.exists() or (not bag and not p.is_file()):
        raise DataError(f"log file {str(p)!r} does not exist")
    if not bag and (joint_topic is not None or wrench_topic is not None):
        raise DataError(f"{where}: joint_topic / wrench_topic apply to bags (.db3, .mcap, a rosbag2 folder) only")
    if columns and (bag or suffix == ".npz"):
        raise DataError(f"{where}: a column mapping applies to CSV and Parquet logs only")
    _check_torque_source(torque_from, gains, n_joints, where)  # before reading a large file
    data, notes = _read_by_format(
        p, bag=bag, n_joints=n_joints, joint_names=names, columns=columns, time_unit=time_unit,
        joint_topic=joint_topic, wrench_topic=wrench_topic, torque_from=torque_from,
    )  # fmt: skip
    if torque_from == "current":
        current = data.pop("current" if "current" in data else "tau")  # a bag's effort field holds the currents
        data["tau"], note = torque_from_current(current, gains, where)
        notes.append(note)
    return _finish(data, where, n_joints, repair, period, notes=tuple(notes))


def _read_by_format(
    p: Path,
    *,
    bag: bool,
    n_joints: int | None,
    joint_names: tuple[str, ...] | None,
    columns: Mapping[str, str] | None,
    time_unit: str | None,
    joint_topic: str | None,
    wrench_topic: str | None,
    torque_from: str,
) -> tuple[dict[str, np.ndarray], list[str]]:
    """The arrays of a bag, an npz file or a table, times relative to the first sample, and the reader's notes
    (arguments as :func:`load_log` takes them, checked there)."""
    where = p.name
    suffix = p.suffix.lower()
    if bag:
        return read_bag(
            p, joint_names=joint_names, n_joints=n_joints, joint_topic=joint_topic, wrench_topic=wrench_topic,
            time_unit=time_unit,
        )  # fmt: skip
    if suffix == ".npz":
        data = _read_npz(p, "current" if torque_from == "current" else "tau")
        data["t"], note = relative_seconds(data["t"], where=where, unit=time_unit)
        return data, [note] if note else []
    if suffix in (".csv", ".parquet", ".pq"):
        return read_table(
            p, n_joints=n_joints, joint_names=joint_names, columns=None if columns is None else dict(columns),
            time_unit=time_unit, torque_from=torque_from,
        )  # fmt: skip
    raise DataError(
        f"{where}: unknown log format {suffix!r}; use .csv, .parquet, .npz, or a ROS 2 bag (.db3, .mcap, folder)"
    )


def _check_torque_source(torque_from: str, gains: npt.ArrayLike | None, n_joints: int | None, where: str) -> None:
    if torque_from not in TORQUE_SOURCES:
        raise ConfigError(f"unknown torque source {torque_from!r}; choose one of: {', '.join(TORQUE_SOURCES)}")
    if torque_from == "current":
        check_gains(gains, n_joints, where)
    elif gains is not None:
        raise ConfigError(
            f"{where}: gains [Nm/A] turn motor currents into torques: give them with torque_from='current'"
        )


def _read_npz(p: Path, torque: str = "tau") -> dict[str, np.ndarray]:
    where = p.name
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:
        raise DataError(f"{where}: cannot read the file as npz: {e}") from e
    allowed = ("t", "q", "dq", torque, "ddq", "wrench")
    unknown = [k for k in arrays if k not in allowed]
    if unknown:
        raise DataError(
            f"{where}: unexpected array(s) {', '.join(map(repr, unknown))}; an npz log holds t, q, dq, {torque} and "
            "optionally ddq, wrench"
        )
    for k in ("t", "q", "dq", torque):
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
