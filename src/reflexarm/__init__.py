"""reflexarm: safe, precise torque control of robot arms in contact.

Joint impedance control, a momentum-based disturbance observer with friction and wrist force/torque
compensation, collision detection and reaction, and two-step friction + rigid-body identification
(Vorndamme, Schappler, Toedtheide, Haddadin, "Soft Robotics for the Hydraulic Atlas Arms").
"""

from reflexarm.errors import ConfigError, DataError, IdentificationError, ModelError, ReflexArmError, SimulationError
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot
from reflexarm.signals import Command, Measurement, Reference

__version__ = "0.1.0"

__all__ = [
    "Command",
    "ConfigError",
    "CoulombViscousFriction",
    "DataError",
    "IdentificationError",
    "Measurement",
    "ModelError",
    "Reference",
    "ReflexArmError",
    "RobotModel",
    "SimulationError",
    "__version__",
    "load_robot",
]
