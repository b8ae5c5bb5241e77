"""``reflexarm ros monitor|control|sim``: the collision node and the simulated robot on ROS 2.

Thin: the nodes live in :mod:`reflexarm.ros`; rclpy is imported only when a command runs (the ``ros`` extra).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from reflexarm.errors import ConfigError

_ROS_HELP = (
    "settings are ROS parameters: a YAML file (--params-file, the '/**: ros__parameters:' layout) and -p NAME:=VALUE "
    "overrides; network traffic is DDS's (keep it on loopback: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)"
)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``ros`` (monitor, control, sim) to the top-level parser."""
    p = sub.add_parser(
        "ros",
        help="ROS 2 nodes (the 'ros' extra): the collision monitor / controller on JointState, the simulated robot",
        description="ROS 2 nodes on rclpy. " + _ROS_HELP,
    )
    rsub = p.add_subparsers(dest="node", metavar="NODE")
    rsub.required = True
    helps = {
        "monitor": "residual, collision events, contact wrench and arrow from JointState (no torque commanded)",
        "control": "the same, and joint effort commands (std_msgs/Float64MultiArray, forward command controller)",
        "sim": "the MuJoCo plant as a node: JointState and wrist wrench at --rate, effort commands in",
    }
    for name, text in helps.items():
        r = rsub.add_parser(name, help=text, description=f"{text}. {_ROS_HELP}")
        r.add_argument("--params-file", type=Path, default=None, metavar="YAML", help="ROS 2 parameter file")
        r.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                       help="set a parameter (repeatable); 'reflexarm ros NODE --list-params' lists them")  # fmt: skip
        r.add_argument("--list-params", action="store_true", help="print the node's parameters and exit")
        r.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                       help="run with SCHED_FIFO priority N (1-99; root or CAP_SYS_NICE), as ros2_control runs "
                       "its loop; the middleware's threads started later inherit it (default 0: the normal "
                       "scheduler)")  # fmt: skip
        r.add_argument("--duration", type=float, default=None, metavar="S",
                       help="stop after S seconds (sim: of simulated time; default: until stopped)")  # fmt: skip
        r.set_defaults(func=_run)


def _table(node: str) -> tuple[tuple[str, Any, str], ...]:
    from reflexarm.ros.config import MONITOR_PARAMETERS, SIM_PARAMETERS

    return SIM_PARAMETERS if node == "sim" else MONITOR_PARAMETERS


def parse_overrides(items: list[str], table: tuple[tuple[str, Any, str], ...]) -> dict[str, Any]:
    """``["threshold:=20", ...]`` -> typed values by name (the type of each parameter's default)."""
    defaults = {name: default for name, default, _ in table}
    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition(":=")
        if not sep:
            raise ConfigError(f"-p expects NAME:=VALUE; got {item!r}")
        if name not in defaults:
            raise ConfigError(f"unknown parameter {name!r}; parameters are: {', '.join(sorted(defaults))}")
        kind = type(defaults[name])
        try:
            if kind is bool:
                if text.lower() not in ("true", "false"):
                    raise ValueError
                out[name] = text.lower() == "true"
            else:
                out[name] = kind(text)
        except ValueError:
            raise ConfigError(f"parameter {name} must be a {kind.__name__}; got {text!r}") from None
    return out


def _import_rclpy() -> None:
    try:
        import rclpy  # noqa: F401
    except ImportError as e:
        raise ConfigError(
            "reflexarm ros needs the 'ros' extra (rclpy, the message packages and Fast DDS from the package "
            f"registry): pip install 'reflexarm[ros]' (make install does it); import failed: {e}"
        ) from e


def _set_realtime_priority(priority: int) -> None:
    """SCHED_FIFO at ``priority`` for this thread and those it starts (0: leave the scheduler alone)."""
    if priority == 0:
        return
    if not 1 <= priority <= 99:
        raise ConfigError(f"--realtime-priority must be in 1-99 (0: off); got {priority}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, AttributeError) as e:
        print(f"reflexarm ros: warning: --realtime-priority {priority} not applied ({e}); the normal scheduler runs "
              "the node", file=sys.stderr)  # fmt: skip


def _run(args: argparse.Namespace) -> int:
    table = _table(args.node)
    if args.list_params:
        for name, default, text in table:
            print(f"{name:24} {default!r:40} {text}")
        return 0
    values = parse_overrides(args.param, table)
    if args.node == "sim" and args.duration is not None:
        values["duration"] = float(args.duration)
    if args.params_file is not None and not args.params_file.is_file():
        raise ConfigError(f"--params-file: no such file {str(args.params_file)!r}")
    _import_rclpy()
    _set_realtime_priority(args.realtime_priority)
    from rclpy.parameter import Parameter

    from reflexarm.ros._node_tools import run_node

    kwargs: dict[str, Any] = {"parameter_overrides": [Parameter(k, value=v) for k, v in values.items()]}
    if args.params_file is not None:
        kwargs["cli_args"] = ["--ros-args", "--params-file", str(args.params_file)]
    if args.node == "sim":
        from reflexarm.ros.sim_node import SimulatedRobot

        def spin(node: Any, executor: Any) -> None:
            node.run(executor)
            s = node.summary()
            print(f"sim: {s['ticks']} ticks ({s['simulated_s']:.3f} s), {s['commands']} commands, "
                  f"{s['rejected_commands']} dropped, {s['lockstep_timeouts']} lockstep timeouts, "
                  f"{s['overruns']} overruns")  # fmt: skip

        return run_node(lambda: SimulatedRobot(**kwargs), spin)
    from reflexarm.ros.monitor_node import CollisionMonitor

    stop_at = None if args.duration is None else time.monotonic() + args.duration

    def spin_monitor(node: Any, executor: Any) -> None:
        while not node.done and (stop_at is None or time.monotonic() < stop_at):
            executor.spin_once(timeout_sec=0.1)

    return run_node(lambda: CollisionMonitor(args.node, **kwargs), spin_monitor)
