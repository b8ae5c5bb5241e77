"""The *true* world: a MuJoCo plant built from the robot's own file, scenes, noisy sensors, a closed-loop
runner and the recorded :class:`Trace`."""

from reflexarm.sim.noise import PAPER_NOISE, SensorNoise
from reflexarm.sim.plant import Plant
from reflexarm.sim.scene import Scene

__all__ = ["PAPER_NOISE", "Plant", "Scene", "SensorNoise"]
