"""What the controller knows: robot models over Pinocchio, friction models, shipped robot files."""

from reflexarm.robots._mjcf import RobotFileWarning
from reflexarm.robots.collision_geometry import CollisionGeometry, LinkSurface, link_collision_geometry
from reflexarm.robots.example_arms import write_ur_like_arm
from reflexarm.robots.frames import FileFrame, list_frames
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.loader import builtin_robots, load_robot
from reflexarm.robots.perturbation import ModelPerturbation, perturb_model
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "CollisionGeometry",
    "CoulombViscousFriction",
    "FileFrame",
    "LinkSurface",
    "ModelPerturbation",
    "RobotFileWarning",
    "RobotModel",
    "builtin_robots",
    "link_collision_geometry",
    "list_frames",
    "load_robot",
    "perturb_model",
    "write_ur_like_arm",
]
