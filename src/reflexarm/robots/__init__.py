"""What the controller knows: robot models over Pinocchio, friction models, shipped robot files."""

from reflexarm.robots._mjcf import RobotFileWarning
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.loader import builtin_robots, load_robot
from reflexarm.robots.perturbation import ModelPerturbation, perturb_model
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "CoulombViscousFriction",
    "ModelPerturbation",
    "RobotFileWarning",
    "RobotModel",
    "builtin_robots",
    "load_robot",
    "perturb_model",
]
