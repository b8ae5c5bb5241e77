"""The real-time part: impedance control (2), momentum observer (4)-(6), collision detection (12),
reaction (13) and the composed :class:`Controller`. Never imports :mod:`reflexarm.sim`."""

from reflexarm.control._setup import detection_friction
from reflexarm.control.collision import CollisionDetector, CollisionEvent, ReactionSettings
from reflexarm.control.contract import FAULT_CODES, InputBounds, TimingStats
from reflexarm.control.controller import MODES, OBSERVER_DISCRETIZATIONS, REACTIONS, Controller
from reflexarm.control.impedance import ImpedanceGains, JointImpedanceController, modal_damping
from reflexarm.control.log_replay import ReplayEvent, ReplayResult, replay
from reflexarm.control.modes import CONTROL_MODES, ControlMode, ModeSchedule, ModeSupervisor, ModeTransition
from reflexarm.control.momentum_observer import MomentumObserver
from reflexarm.control.observer import DisturbanceObserver

__all__ = [
    "CONTROL_MODES",
    "FAULT_CODES",
    "MODES",
    "REACTIONS",
    "OBSERVER_DISCRETIZATIONS",
    "CollisionDetector",
    "CollisionEvent",
    "ControlMode",
    "Controller",
    "DisturbanceObserver",
    "ImpedanceGains",
    "InputBounds",
    "JointImpedanceController",
    "ModeSchedule",
    "ModeSupervisor",
    "ModeTransition",
    "ReactionSettings",
    "ReplayEvent",
    "ReplayResult",
    "MomentumObserver",
    "TimingStats",
    "modal_damping",
    "detection_friction",
    "replay",
]
