"""The *true* world: a MuJoCo plant built from the robot's own file, scenes (padded cinderblock, elbow
push, end-effector force step), noisy sensors, a closed-loop runner (Python, or compiled:
:func:`run_compiled`) and the recorded :class:`Trace`."""

from reflexarm.sim.cinderblock import Cinderblock
from reflexarm.sim.compiled_loop import compiled_reason, run_compiled, run_fast
from reflexarm.sim.compiled_stream import stream_compiled, stream_fast
from reflexarm.sim.elbow_stick import ElbowStick
from reflexarm.sim.end_effector_force import EndEffectorForce
from reflexarm.sim.hand_push import HandPush
from reflexarm.sim.link_force import LinkForce
from reflexarm.sim.noise import PAPER_NOISE, SensorNoise
from reflexarm.sim.plant import Plant
from reflexarm.sim.recording import RunStatistics
from reflexarm.sim.runner import run_closed_loop, stream_closed_loop
from reflexarm.sim.scene import Scene
from reflexarm.sim.trace import Trace, TraceWriter
from reflexarm.sim.trajectory import JointTrajectory

__all__ = [
    "PAPER_NOISE",
    "Cinderblock",
    "ElbowStick",
    "EndEffectorForce",
    "HandPush",
    "JointTrajectory",
    "LinkForce",
    "Plant",
    "RunStatistics",
    "Scene",
    "SensorNoise",
    "Trace",
    "TraceWriter",
    "compiled_reason",
    "run_closed_loop",
    "run_compiled",
    "run_fast",
    "stream_closed_loop",
    "stream_compiled",
    "stream_fast",
]
