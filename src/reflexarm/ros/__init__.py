"""reflexarm on ROS 2 (the ``ros`` extra: rclpy and the message packages from the package registry).

``reflexarm ros monitor|control`` (:class:`~reflexarm.ros.monitor_node.CollisionMonitor`) runs the Controller on a
live ``sensor_msgs/JointState`` stream; ``reflexarm ros sim`` (:class:`~reflexarm.ros.sim_node.SimulatedRobot`)
is the MuJoCo plant as a node. This package's ``__init__`` imports only the configuration (no rclpy): the node
modules import rclpy.
"""

from reflexarm.ros.config import MONITOR_PARAMETERS, SIM_PARAMETERS, MonitorConfig, SimConfig

__all__ = ["MONITOR_PARAMETERS", "MonitorConfig", "SIM_PARAMETERS", "SimConfig"]
