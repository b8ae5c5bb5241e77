"""The nodes' configuration: one table of ROS parameters (name, default, meaning), read into frozen dataclasses.

Both nodes take their settings as ROS parameters, so a YAML file (``--params-file``, the ``/**: ros__parameters:``
layout of ROS 2) and ``-p name:=value`` overrides configure them the ROS way. Nothing here imports rclpy: the
tables and the checks are plain Python, and the node modules declare each entry with
``declare_parameter(name, default, ParameterDescriptor(description=...))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from reflexarm.control.collision.react import REACTIONS
from reflexarm.errors import ConfigError

__all__ = ["MODES", "MONITOR_PARAMETERS", "REFERENCES", "SCENES", "SIM_PARAMETERS", "MonitorConfig", "SimConfig"]

#: What the collision node does: ``monitor`` estimates only (residual, detection, isolation, force; no torque
#: leaves it), ``control`` also publishes the controller's joint efforts.
MODES = ("monitor", "control")

#: Where the control node's joint reference comes from: ``hold`` the first measured posture; ``topic`` a
#: ``sensor_msgs/JointState`` on ``reference_topic`` (position, velocity; by name); or a scene's trajectory
#: (the demo's swing, the link collision's motion, the free-motion swing) timed from the first stamp heard.
REFERENCES = ("hold", "topic", "demo", "link", "free")

#: Scenes of the simulated robot (``reflexarm ros sim``): the demo's cinderblock, the link collision's stick,
#: the demo's swing without obstacle, or nothing at all.
SCENES = ("demo", "link", "free", "none")

# (name, default, description): the order is the order of the docs
MONITOR_PARAMETERS: tuple[tuple[str, Any, str], ...] = (
    ("robot", "atlas_v5_left_arm", "built-in robot name or robot file (.urdf / MJCF .xml)"),
    ("model_file", "", "identified model (written by 'reflexarm identify dynamics'); '' = the robot file's model"),
    ("model_error", 0.0, "simulation only: uniform model errors within +- this fraction (0 = none)"),
    ("model_seed", 0, "seed of model_error"),
    ("threshold", "11", "zeta [Nm]: one level, a comma list per joint, or a thresholds.json of tune-thresholds"),
    ("observer_gain", 5.0, "K_o of the observer [1/s]"),
    ("detection_observer_gain", 0.0, "K_o of a second, detecting observer [1/s]; 0 = none"),
    ("detection_friction_band", 0.0,
     "the detecting observer subtracts the friction model in this velocity band [rad/s]; 0 = a thresholds.json's, "
     "else none"),
    ("detection_filter_gain", 0.0,
     "K_f of a second stage on the detecting residual [1/s]; 0 = a thresholds.json's, else none"),
    ("observer_discretization", "euler", "euler or exact"),
    ("reaction", "gravity", "reaction to a collision: " + ", ".join(REACTIONS)),
    ("stiffness", 300.0, "joint stiffness K [Nm/rad] (control mode)"),
    ("reference", "hold", "joint reference (control mode): " + ", ".join(REFERENCES)),
    ("joint_states_topic", "/joint_states", "sensor_msgs/JointState input"),
    ("wrench_topic", "", "geometry_msgs/WrenchStamped of the wrist sensor; '' = no sensor"),
    ("reference_topic", "~/reference", "sensor_msgs/JointState reference (reference = topic)"),
    ("command_topic", "/forward_effort_controller/commands", "std_msgs/Float64MultiArray efforts (control mode)"),
    ("joint_state_timeout", 0.05, "no JointState for this long [s] is a fault (> 0)"),
    ("wrench_timeout", 0.05, "no wrench for this long [s] is a fault (> 0)"),
    ("max_stamp_gap", 0.1, "a stamp this far [s] past the last one is a clock jump (a fault)"),
    ("watchdog_period", 0.01, "period of the staleness check [s]"),
    ("rearm_after", 0.0, "monitor mode: re-arm after the residual stayed below zeta this long [s]; 0 = latch"),
    ("qos_depth", 50, "depth of the input subscriptions (reliable, keep last)"),
    ("record_bag", "", "folder of a rosbag2 bag to record the inputs into ('' = none; must not exist)"),
    ("summary_file", "", "JSON file with the events, faults and latencies written at exit ('' = none)"),
)

SIM_PARAMETERS: tuple[tuple[str, Any, str], ...] = (
    ("robot", "atlas_v5_left_arm", "built-in robot name or robot file (.urdf / MJCF .xml)"),
    ("scene", "demo", "scene: " + ", ".join(SCENES)),
    ("seed", 0, "seed of the sensor noise (the paper's levels)"),
    ("noise", True, "sensor noise on (the paper's levels)"),
    ("rate", 1000.0, "control rate [Hz]: the period of the plant's step"),
    ("lockstep", False, "step only when the command answering the last JointState arrived (no wall clock)"),
    ("lockstep_timeout", 2.0, "lockstep: wait this long [s] for a command, then hold the last one"),
    ("duration", 0.0, "simulated time to run [s]; 0 = until stopped"),
    ("joint_states_topic", "/joint_states", "sensor_msgs/JointState output"),
    ("wrench_topic", "~/wrench", "geometry_msgs/WrenchStamped of the wrist sensor"),
    ("command_topic", "/forward_effort_controller/commands", "std_msgs/Float64MultiArray efforts input"),
    ("wait_for_subscribers", 1, "wait until this many JointState subscribers are matched before starting"),
    ("summary_file", "", "JSON file with the run's counts written at exit ('' = none)"),
)


def _positive(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"parameter {name} must be a positive number; got {value!r}")
    return float(value)


def _choice(name: str, value: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ConfigError(f"parameter {name} must be one of {', '.join(choices)}; got {value!r}")
    return value


@dataclass(frozen=True)
class MonitorConfig:
    """The collision node's settings (see :data:`MONITOR_PARAMETERS` for each one's meaning and unit)."""

    mode: str
    robot: str
    model_file: str
    model_error: float
    model_seed: int
    threshold: str
    observer_gain: float
    detection_observer_gain: float
    detection_friction_band: float
    detection_filter_gain: float
    observer_discretization: str
    reaction: str
    stiffness: float
    reference: str
    joint_states_topic: str
    wrench_topic: str
    reference_topic: str
    command_topic: str
    joint_state_timeout: float
    wrench_timeout: float
    max_stamp_gap: float
    watchdog_period: float
    rearm_after: float
    qos_depth: int
    record_bag: str
    summary_file: str

    def __post_init__(self) -> None:
        _choice("mode", self.mode, MODES)
        _choice("reaction", self.reaction, REACTIONS)
        _choice("reference", self.reference, REFERENCES)
        _choice("observer_discretization", self.observer_discretization, ("euler", "exact"))
        for name in ("observer_gain", "stiffness", "joint_state_timeout", "wrench_timeout", "max_stamp_gap",
                     "watchdog_period"):  # fmt: skip
            _positive(name, getattr(self, name))
        nonneg = (self.detection_observer_gain, self.detection_friction_band, self.detection_filter_gain,
                  self.rearm_after)  # fmt: skip
        if not all(math.isfinite(v) and v >= 0 for v in nonneg) or not 0 <= self.model_error < 1:
            raise ConfigError(
                "detection_observer_gain, detection_friction_band, detection_filter_gain and rearm_after must be "
                f">= 0 and model_error in [0, 1); got {self.detection_observer_gain!r}, "
                f"{self.detection_friction_band!r}, {self.detection_filter_gain!r}, {self.rearm_after!r}, "
                f"{self.model_error!r}"
            )
        if self.qos_depth < 1:
            raise ConfigError(f"parameter qos_depth must be >= 1; got {self.qos_depth!r}")
        if not self.joint_states_topic:
            raise ConfigError("parameter joint_states_topic must name a topic; got ''")

    @classmethod
    def from_values(cls, mode: str, values: dict[str, Any]) -> MonitorConfig:
        """The config from parameter values by name (missing ones take their defaults)."""
        return cls(mode=mode, **_with_defaults(MONITOR_PARAMETERS, values))


@dataclass(frozen=True)
class SimConfig:
    """The simulated robot node's settings (see :data:`SIM_PARAMETERS`)."""

    robot: str
    scene: str
    seed: int
    noise: bool
    rate: float
    lockstep: bool
    lockstep_timeout: float
    duration: float
    joint_states_topic: str
    wrench_topic: str
    command_topic: str
    wait_for_subscribers: int
    summary_file: str

    def __post_init__(self) -> None:
        _choice("scene", self.scene, SCENES)
        _positive("rate", self.rate)
        _positive("lockstep_timeout", self.lockstep_timeout)
        if self.duration < 0 or self.wait_for_subscribers < 0:
            raise ConfigError(
                f"duration and wait_for_subscribers must be >= 0; got {self.duration!r}, {self.wait_for_subscribers!r}"
            )

    @classmethod
    def from_values(cls, values: dict[str, Any]) -> SimConfig:
        """The config from parameter values by name (missing ones take their defaults)."""
        return cls(**_with_defaults(SIM_PARAMETERS, values))


def _with_defaults(table: tuple[tuple[str, Any, str], ...], values: dict[str, Any]) -> dict[str, Any]:
    known = {name for name, _, _ in table}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"unknown parameters {unknown}; parameters are: {', '.join(sorted(known))}")
    out = {}
    for name, default, _ in table:
        value = values.get(name, default)
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not type(default):
            raise ConfigError(f"parameter {name} must be a {type(default).__name__}; got {value!r}")
        out[name] = value
    return out


def parameter_names(config_type: type[MonitorConfig] | type[SimConfig]) -> list[str]:
    """The dataclass' field names (for tests: every field has a parameter)."""
    return [f.name for f in fields(config_type)]
