"""What the controller knows: robot models over Pinocchio, friction models, shipped robot files."""

from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel, builtin_robots, load_robot

__all__ = ["CoulombViscousFriction", "RobotModel", "builtin_robots", "load_robot"]
