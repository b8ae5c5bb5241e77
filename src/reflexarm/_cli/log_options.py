"""The log options of every command that reads a robot log: ``--columns``, ``--time-unit``,
``--joint-topic``, ``--wrench-topic`` (one parser, one loader: every command reads a log the same way,
with :func:`reflexarm.ident.load_log`, and prints what the reader recognized, converted and left out)."""

from __future__ import annotations

import argparse
import warnings
from typing import Any

#: The units of ``--time-unit``: the keys of :data:`reflexarm.logs.TIME_UNITS`, spelled out here so
#: that registering the option does not import the identification package (tests/test_cli_startup.py
#: checks that the two agree).
TIME_UNIT_CHOICES = ("s", "ms", "us", "ns")


def add_log_options(p: argparse.ArgumentParser) -> None:
    """Add ``--columns``, ``--time-unit``, ``--joint-topic`` and ``--wrench-topic`` to ``p``."""
    g = p.add_argument_group("logs (CSV / Parquet / npz / ROS 2 bags: .db3, .mcap or a rosbag2 folder)")
    g.add_argument(
        "--columns",
        default=None,
        metavar="KEY=TEMPLATE,...",
        help="which columns hold what, when not found automatically (schema q_1.., joint-named columns such as "
        "position_<joint> or <joint>/position, the ROS JointState layout position.0..); keys t, q, dq, tau, ddq, "
        "wrench; placeholders {joint} (joint name), {i} (1-based), {i0} (0-based), {axis} (fx..mz), "
        "{ros_axis} (force.x..torque.z); e.g. --columns 't=stamp,q=pos_{joint},dq=vel_{joint},tau=trq_{joint}'",
    )
    g.add_argument(
        "--time-unit",
        choices=TIME_UNIT_CHOICES,
        default=None,
        help="unit of the log's time stamps (default: from the column name, e.g. t_ns, else from their "
        "magnitude and spacing); times are always made relative to the first sample",
    )
    g.add_argument(
        "--joint-topic", default=None, help="bags: the sensor_msgs/msg/JointState topic (default: the only one)"
    )
    g.add_argument(
        "--wrench-topic",
        default=None,
        help="bags: a geometry_msgs/msg/WrenchStamped topic of the wrist sensor, interpolated at the joint samples",
    )


def load_log_from_args(args: argparse.Namespace, path: str, robot: Any) -> Any:
    """The :class:`~reflexarm.ident.RobotLog` at ``path`` for ``robot`` (joints mapped by its joint names),
    read with the log options of ``args``; the reader's notes are printed (repairs as warnings)."""
    from reflexarm.logs import load_log, parse_column_mapping

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = load_log(
            path,
            joint_names=tuple(robot.joint_names),
            columns=parse_column_mapping(getattr(args, "columns", None)),
            time_unit=getattr(args, "time_unit", None),
            joint_topic=getattr(args, "joint_topic", None),
            wrench_topic=getattr(args, "wrench_topic", None),
        )
    cores = [str(w.message).split(": ", 1)[-1] for w in caught]  # a warning's text after "file: "
    for note in log.notes:
        print(("warning: " if any(c in note for c in cores) else "log: ") + note)
    for w, core in zip(caught, cores, strict=True):  # warnings that are not in the notes are passed on
        if not any(core in note for note in log.notes):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return log
