"""Which links of a robot file the identification lumps into each moving link, and what the links behind
locked joints (an arm cut out of a bigger file: a gripper's fingers) contribute.

Each joint j of the arm moves one link (its child in the file); other links are lumped into it: links fixed
to it (URDF fixed joints, MJCF bodies without joints) and, for a cut arm, links behind joints that are
locked at a position. :func:`locked_links` sorts them and computes the locked links' share of each
joint's 10 inertial parameters (about the joint frame, at the locked positions) by loading the file with
every other link of the arm made massless, with the same cut.
"""

from __future__ import annotations

import copy
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.ident.export._robot_xml import (
    behind_locked_joint,
    find_element,
    read_xml,
    relocate_paths,
    set_inertial,
    write_xml,
)
from reflexarm.robots.loader import load_robot
from reflexarm.robots.robot_model import RobotModel


@dataclass(frozen=True)
class LockedLinks:
    """The links of ``robot``'s file per joint.

    Attributes:
        fmt: ``"urdf"`` or ``"mjcf"``.
        groups: per joint, the link it moves and the other links lumped into it.
        fixed: lumped links rigidly fixed to a moving link.
        behind: lumped links behind a locked joint.
        parameters: (10 n,) the ``behind`` links' share of each joint's inertial parameters, or None.
    """

    fmt: str
    groups: tuple[tuple[str, tuple[str, ...]], ...]
    fixed: tuple[str, ...]
    behind: frozenset[str]
    parameters: np.ndarray | None


def _body_frames(robot: RobotModel, joint: int) -> list[pin.Frame]:
    """BODY frames moved by ``joint`` (1-based Pinocchio joint index): the moving link first."""
    return [f for f in robot.pin_model.frames if f.type == pin.FrameType.BODY and f.parentJoint == joint]


def link_groups(robot: RobotModel) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """Per joint: the link it moves and the other links attached to that link (lumped into its inertia)."""
    groups = []
    for j in range(1, robot.pin_model.njoints):
        frames = _body_frames(robot, j)
        if not frames:
            raise ModelError(
                f"joint {robot.joint_names[j - 1]!r} moves no link of {robot.name!r}; cannot write it back"
            )
        groups.append((frames[0].name, tuple(f.name for f in frames[1:])))
    return tuple(groups)


def robot_file(robot: RobotModel) -> tuple[Path, str]:
    """The robot's file and its format (``"urdf"`` or ``"mjcf"``); ModelError if it has none."""
    if robot.source is None or not Path(robot.source).is_file():
        raise ModelError(f"robot {robot.name!r} has no robot file to copy (source {robot.source!r})")
    src = Path(robot.source)
    return src, "urdf" if src.suffix.lower() == ".urdf" else "mjcf"


def locked_links(robot: RobotModel) -> LockedLinks:
    """Sort the lumped links of ``robot``'s file and compute the locked ones' share (module docstring)."""
    src, fmt = robot_file(robot)
    root = read_xml(src)
    groups = link_groups(robot)
    locked = set(robot.cut.locked) if robot.cut is not None else set()
    behind = frozenset(
        link for main, links in groups for link in links if behind_locked_joint(root, fmt, link, main, locked)
    )
    fixed = tuple(link for _, links in groups for link in links if link not in behind)
    if not behind:
        return LockedLinks(fmt, groups, fixed, behind, None)
    tag = "link" if fmt == "urdf" else "body"
    probe = copy.deepcopy(root)
    for name in [main for main, _ in groups] + list(fixed):
        set_inertial(fmt, find_element(probe, tag, name, src.name), 0.0, np.zeros(3), np.zeros((3, 3)))
    with tempfile.TemporaryDirectory() as tmp:
        relocate_paths(probe, fmt, src.parent, Path(tmp))
        path = write_xml(probe, Path(tmp) / src.name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the file's notes were given when the robot was loaded
            only_locked = load_robot(path, **robot.load_arguments())
    return LockedLinks(fmt, groups, fixed, behind, only_locked.inertial_parameters())
