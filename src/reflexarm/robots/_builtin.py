"""The robots shipped with reflexarm (private; use :func:`reflexarm.robots.builtin_robots`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ASSETS", "BuiltinRobot"]

ASSETS = Path(__file__).resolve().parent / "assets"


@dataclass(frozen=True)
class BuiltinRobot:
    """A robot shipped with reflexarm."""

    name: str
    file: str
    ee_frame: str
    sensor_frame: str
    home: tuple[float, ...]
    description: str
    velocity_limit: tuple[float, ...] = ()  # MJCF has no joint velocity limits: given here [rad/s]

    @property
    def path(self) -> Path:
        return ASSETS / self.file


_BUILTINS: dict[str, BuiltinRobot] = {
    "atlas_v5_left_arm": BuiltinRobot(
        name="atlas_v5_left_arm",
        file="atlas_v5_left_arm.xml",
        ee_frame="ee",
        sensor_frame="wrist_ft",
        home=(-0.3, -1.1, 1.6, 1.2, 0.0, 0.2, 0.0),
        description="Atlas v5 left arm (4 hydraulic + 3 electric joints), torso fixed upright, "
        "true friction from Table I of the paper",
        velocity_limit=(12.0, 12.0, 12.0, 12.0, 10.0, 10.0, 10.0),
    ),
    "panda": BuiltinRobot(
        name="panda",
        file="panda.xml",
        ee_frame="ee",
        sensor_frame="wrist_ft",
        home=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
        description="Franka Emika Panda (no hand), kinematics of the Franka description, "
        "inertial values of Gaz et al. 2019",
        velocity_limit=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    ),
    "iiwa14": BuiltinRobot(
        name="iiwa14",
        file="iiwa14.xml",
        ee_frame="ee",
        sensor_frame="wrist_ft",
        home=(0.0, 0.6, 0.0, -1.3, 0.0, 1.0, 0.0),
        description="KUKA LBR iiwa 14 R820 (no gripper), KUKA's published kinematics and limits, inertial values "
        "of Drake's iiwa14 description, assumed small joint friction (a low-friction arm)",
        velocity_limit=tuple(math.radians(v) for v in (85, 85, 100, 75, 130, 135, 135)),  # KUKA's deg/s
    ),
}
