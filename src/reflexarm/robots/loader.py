"""Loading a robot: a built-in one by name, or a user's URDF/MJCF file, optionally cut to an arm."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from reflexarm.errors import ModelError
from reflexarm.robots._builtin import _BUILTINS, BuiltinRobot
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = ["builtin_robots", "load_robot"]


def builtin_robots() -> dict[str, BuiltinRobot]:
    """The robots shipped with reflexarm, by name."""
    return dict(_BUILTINS)


def load_robot(
    name_or_path: str | os.PathLike[str],
    *,
    ee_frame: str | None = None,
    sensor_frame: str | None = None,
    friction: CoulombViscousFriction | None = None,
    base: str | None = None,
    tip: str | None = None,
    locked: Mapping[str, float] | None = None,
) -> RobotModel:
    """Load a built-in robot by name, or a user's URDF/MJCF file by path.

    A whole robot (humanoid, arm + gripper) is cut to the serial arm from link ``base`` to link ``tip``:
    every other joint is locked (Pinocchio's reduced model; the plant freezes the same joints) and the
    bodies it carried keep their mass, rigidly attached. A floating base in the file is fixed where the
    file puts it, with a note. :attr:`RobotModel.cut` records base, tip and locks.

    Args:
        name_or_path: a name from :func:`builtin_robots` or a path to a ``.urdf`` or ``.xml`` (MJCF) file.
        ee_frame: end-effector frame (built-ins default to ``"ee"``, cut files to the ``tip`` link; other
            files must name one). A frame past the tip (a finger of a cut-off gripper) moves rigidly with
            the tip (a note says so); one fixed in the world is refused.
        sensor_frame: wrist force/torque sensor frame; defaults to ``ee_frame``.
        friction: the model's friction; defaults to the file's joint ``frictionloss``/``damping``
            (MJCF) or ``<dynamics friction damping>`` (URDF).
        base: link the arm starts from (default: the root link); fixed in the world.
        tip: last link of the arm (needed when the file is a tree).
        locked: joint name -> position [rad or m] of a joint off the chain. Default: the MJCF's "home"
            keyframe, else 0, and for a coupled joint (URDF ``<mimic>``) where its leader's lock puts it;
            clipped to the joint's limits (with a note).

    Raises:
        ModelError: unknown robot name, unreadable or malformed file, missing frame or link, a tree
            without ``tip``, a lock on an unknown or chain joint.
    """
    key = str(name_or_path)
    if key in _BUILTINS:
        b = _BUILTINS[key]
        robot = RobotModel.from_file(
            b.path,
            ee_frame=ee_frame or (tip if tip is not None else b.ee_frame),
            sensor_frame=sensor_frame or (None if tip is not None else b.sensor_frame),
            friction=friction,
            name=b.name,
            home=b.home if base is None and tip is None else None,
            base=base,
            tip=tip,
            locked=locked,
        )
        if b.velocity_limit and robot.cut is None:
            robot.pin_model.velocityLimit = np.asarray(b.velocity_limit, dtype=float)
        return robot
    path = Path(key)
    if path.suffix.lower() not in (".urdf", ".xml", ".mjcf") and not path.exists():
        raise ModelError(
            f"unknown robot {key!r}; built-in robots are: {', '.join(sorted(_BUILTINS))} "
            "(or give a path to a .urdf or MJCF .xml file)"
        )
    if not path.is_file():
        raise ModelError(f"robot file {key!r} does not exist")
    return RobotModel.from_file(
        path, ee_frame=ee_frame, sensor_frame=sensor_frame, friction=friction, base=base, tip=tip, locked=locked
    )
