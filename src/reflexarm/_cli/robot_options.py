"""The robot options every command takes: ``--robot NAME|FILE`` with ``--ee-frame``, ``--sensor-frame``,
``--base``, ``--tip`` and ``--lock`` (one parser, one loader, so every command reads a user's arm the same way)."""

from __future__ import annotations

import argparse
from typing import Any

from reflexarm.errors import ConfigError

DEFAULT_ROBOT = "atlas_v5_left_arm"


def add_robot_options(p: argparse.ArgumentParser, *, default: str = DEFAULT_ROBOT) -> None:
    """Add ``--robot``, ``--ee-frame``, ``--sensor-frame``, ``--base``, ``--tip`` and ``--lock`` to ``p``."""
    g = p.add_argument_group("robot")
    g.add_argument("--robot", default=default, help=f"built-in name or .urdf/.xml (MJCF) file (default {default})")
    g.add_argument("--ee-frame", default=None, help="end-effector frame (user robot files; default: the tip link)")
    g.add_argument("--sensor-frame", default=None, help="wrist force/torque sensor frame (default: the ee frame)")
    g.add_argument("--base", default=None, help="link the arm starts from, to cut an arm out of a tree (humanoid)")
    g.add_argument("--tip", default=None, help="last link of the arm, to cut it out of a tree (e.g. drop a gripper)")
    g.add_argument(
        "--lock",
        action="append",
        default=[],
        metavar="JOINT=VALUE",
        help="position [rad or m] at which a joint outside the base..tip chain is locked (repeatable; default 0)",
    )


def parse_locks(items: list[str]) -> dict[str, float]:
    """``["torso_y=0.1", ...]`` -> ``{"torso_y": 0.1}``; a malformed item is a :class:`ConfigError`."""
    locks: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            locks[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--lock expects JOINT=VALUE (e.g. back_bkz=0.0); got {item!r}") from None
    return locks


def load_robot_from_args(args: argparse.Namespace) -> Any:
    """The :class:`~reflexarm.robots.RobotModel` the robot options of ``args`` name."""
    from reflexarm.robots import load_robot

    return load_robot(args.robot, **robot_kwargs(args))


def robot_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of ``load_robot(args.robot, ...)`` that the robot options of ``args`` give."""
    kwargs: dict[str, Any] = {
        "ee_frame": getattr(args, "ee_frame", None),
        "sensor_frame": getattr(args, "sensor_frame", None),
    }
    base, tip = getattr(args, "base", None), getattr(args, "tip", None)
    locks = parse_locks(getattr(args, "lock", []) or [])
    if base is not None or tip is not None or locks:
        kwargs.update(base=base, tip=tip, locked=locks)
    return kwargs
