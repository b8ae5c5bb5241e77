"""reflexarm: safe, precise torque control of robot arms in contact.

Joint impedance control, a momentum-based disturbance observer with friction and wrist force/torque
compensation, collision detection and reaction, and two-step friction + rigid-body identification
(Vorndamme, Schappler, Toedtheide, Haddadin, "Soft Robotics for the Hydraulic Atlas Arms").

``Controller`` (from :mod:`reflexarm.control`) is imported on first use: it pulls in the compiled
control core and numba, which a script that only loads a robot or a log does not need.
"""

import os as _os
import sys as _sys

# MuJoCo picks its OpenGL backend once, when ``mujoco`` is first imported (reflexarm.robots imports it
# below). On a Linux machine without a display (a server, CI, a container) the only backend that renders
# offscreen is EGL, so the scene stills and videos of reflexarm.sim.video need MUJOCO_GL=egl set before
# that import. A value the user set is kept; with a display MuJoCo's default (GLFW) stays.
if (
    _sys.platform.startswith("linux")
    and "MUJOCO_GL" not in _os.environ
    and not _os.environ.get("DISPLAY")
    and not _os.environ.get("WAYLAND_DISPLAY")
    and "mujoco" not in _sys.modules
):
    _os.environ["MUJOCO_GL"] = "egl"

from typing import TYPE_CHECKING  # noqa: E402

from reflexarm.errors import (  # noqa: E402
    ConfigError,
    DataError,
    IdentificationError,
    ModelError,
    ReflexArmError,
    SimulationError,
)
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot  # noqa: E402
from reflexarm.signals import Command, Measurement, Reference  # noqa: E402

if TYPE_CHECKING:
    from reflexarm.control import Controller

__version__ = "0.1.0"

__all__ = [
    "Command",
    "ConfigError",
    "Controller",
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


def __getattr__(name: str) -> object:
    if name == "Controller":
        from reflexarm.control import Controller

        return Controller
    raise AttributeError(f"module 'reflexarm' has no attribute {name!r}")
