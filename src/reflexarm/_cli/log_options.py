"""The log options of every command that reads a robot log: ``--columns``, ``--time-unit``,
``--torque-from``, ``--gains``, ``--joint-topic``, ``--wrench-topic`` (one parser, one loader: every command
reads a log the same way, with :func:`reflexarm.logs.load_log`, prints what the reader recognized, converted
and left out, and holds the log against the robot as identification does)."""

from __future__ import annotations

import argparse
import warnings
from typing import Any

from reflexarm.errors import ConfigError

#: The units of ``--time-unit``: the keys of :data:`reflexarm.logs.TIME_UNITS`, spelled out here so
#: that registering the option does not import the identification package (tests/test_cli_startup.py
#: checks that the two agree).
TIME_UNIT_CHOICES = ("s", "ms", "us", "ns")
#: The sources of ``--torque-from`` (:data:`reflexarm.logs.columns.TORQUE_SOURCES`, spelled out likewise).
TORQUE_SOURCE_CHOICES = ("torque", "current")


def add_log_options(p: argparse.ArgumentParser) -> None:
    """Add ``--columns``, ``--time-unit``, ``--torque-from``, ``--gains``, ``--joint-topic`` and
    ``--wrench-topic`` to ``p`` (any command that reads robot logs)."""
    g = p.add_argument_group("logs (CSV / Parquet / npz / ROS 2 bags: .db3, .mcap or a rosbag2 folder)")
    g.add_argument(
        "--columns",
        default=None,
        metavar="KEY=SPEC,...",
        help="which columns hold what, when not found automatically (schema q_1.., joint-named columns such as "
        "position_<joint> or <joint>/position, the ROS JointState layout position.0..); keys t, q, dq, tau, ddq, "
        "current (alias cur), wrench. SPEC is a name template with placeholders {joint} (joint name), {i} "
        "(1-based), {i0} (0-based), {axis} (fx..mz), {ros_axis} (force.x..torque.z), e.g. "
        "'t=stamp,q=pos_{joint},dq=vel_{joint},tau=trq_{joint}'; or positions in the file, counted from 0 with the "
        "end excluded as in Python, one column per joint in the model's order: 't=0,q=1:7,dq=7:13,cur=13:19' "
        "(q=1:13:2 takes every second column; a CSV file whose first row is numbers has no header and is read "
        "this way only); a SPEC may end in *SCALE, which multiplies the values: tau=trq_{i}*0.001 (mNm), "
        "q=1:7*0.0174533 (degrees)",
    )
    g.add_argument(
        "--time-unit",
        choices=TIME_UNIT_CHOICES,
        default=None,
        help="unit of the log's time stamps (default: from the column name, e.g. t_ns, else from their "
        "magnitude and spacing); times are always made relative to the first sample",
    )
    g.add_argument(
        "--torque-from",
        choices=TORQUE_SOURCE_CHOICES,
        default="torque",
        help="where the measured torque comes from: 'torque' (default: tau columns, a JointState's effort) or "
        "'current': motor currents [A] (key current/cur of --columns, columns current_1.. or current_<joint>, a "
        "bag's JointState effort) times --gains",
    )
    g.add_argument(
        "--gains",
        default=None,
        metavar="G1,G2,...",
        help="with --torque-from current: one gain per joint [Nm/A] (motor torque constant x gear ratio) in the "
        "robot's joint order, e.g. --gains 0.1,0.1,0.1,0.1,0.1,0.1",
    )
    g.add_argument(
        "--joint-topic", default=None, help="bags: the sensor_msgs/msg/JointState topic (default: the only one)"
    )
    g.add_argument(
        "--wrench-topic",
        default=None,
        help="bags: a geometry_msgs/msg/WrenchStamped topic of the wrist sensor, interpolated at the joint samples",
    )


def torque_source(args: argparse.Namespace) -> tuple[str, Any]:
    """(``--torque-from``, the ``--gains`` [Nm/A] or None) of ``args``; gains without currents are refused."""
    from reflexarm._cli.ident_common import parse_floats

    torque_from = getattr(args, "torque_from", "torque") or "torque"
    gains = parse_floats(getattr(args, "gains", None), "--gains")
    if gains is not None and torque_from != "current":
        raise ConfigError("--gains [Nm/A] turn motor currents into torques: give them with --torque-from current")
    return torque_from, gains


def load_log_from_args(args: argparse.Namespace, path: str, robot: Any, *, check: bool = True) -> Any:
    """The :class:`~reflexarm.logs.RobotLog` at ``path`` for ``robot`` (joints mapped by its joint names),
    read with the log options of ``args``; the reader's notes are printed (repairs as warnings).

    With ``check`` (the default) the log is held against ``robot`` as identification does
    (:func:`~reflexarm.logs.plausibility.check_log_against_robot`: limits far exceeded, positions against
    velocities, continuous joints in degrees, a torque on another scale than the model's), so that every
    command refuses the same implausible log with the same message.
    """
    from reflexarm.logs import load_log, parse_column_mapping
    from reflexarm.logs.plausibility import check_log_against_robot

    torque_from, gains = torque_source(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = load_log(
            path,
            joint_names=tuple(robot.joint_names),
            columns=parse_column_mapping(getattr(args, "columns", None)),
            time_unit=getattr(args, "time_unit", None),
            joint_topic=getattr(args, "joint_topic", None),
            wrench_topic=getattr(args, "wrench_topic", None),
            torque_from=torque_from,
            gains=gains,
        )
    cores = [str(w.message).split(": ", 1)[-1] for w in caught]  # a warning's text after "file: "
    for note in log.notes:
        print(("warning: " if any(c in note for c in cores) else "log: ") + note)
    for w, core in zip(caught, cores, strict=True):  # warnings that are not in the notes are passed on
        if not any(core in note for note in log.notes):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if check:
        check_log_against_robot(log, robot)
    return log
