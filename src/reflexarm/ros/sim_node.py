"""``reflexarm ros sim``: the MuJoCo plant (:class:`reflexarm.sim.Plant`) as a robot on the other side of the wire.

Each control period it publishes the measurement (``sensor_msgs/JointState``: the robot's joint names, position,
velocity, and the measured joint torque in ``effort``; then ``geometry_msgs/WrenchStamped``, the wrist sensor in
its frame) and applies the last effort command it took (``std_msgs/Float64MultiArray``, ros2_control's forward
command controller layout: one value per joint, the robot's order) over the next period. A command of the wrong
length or with non-finite values is dropped with a warning (as the forward command controller does).

Stamps are the simulated time from the wall clock's time at the start: ``start + k * period`` (integer ns).

Pacing: real time at ``rate`` (a busy wait for the last fraction of each period; commands are taken while
waiting), or ``lockstep``: each step waits for the first command that arrives after the tick's JointState (no
wall clock at all, so a run over DDS equals the in-process one). Lockstep takes the first command after each
JointState as its answer: a controller that publishes other commands in between (e.g. a safe command on a
stale-input fault) shifts it, so run the controller with a staleness timeout longer than the slowest tick.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from reflexarm.errors import SimulationError
from reflexarm.ros._node_tools import declare_parameters, reliable
from reflexarm.ros.config import SIM_PARAMETERS, SimConfig

__all__ = ["SimulatedRobot"]

#: The last stretch of a period is busy-waited (sleeping in the middleware's wait is coarser) [s].
BUSY_WAIT = 0.0003


class SimulatedRobot(Node):
    """The simulated arm node (see the module docstring; settings: :data:`~reflexarm.ros.config.SIM_PARAMETERS`).
    Drive it with :meth:`run`."""

    def __init__(self, *, name: str = "reflexarm_sim", **node_kwargs: Any) -> None:
        super().__init__(name, **node_kwargs)
        cfg = self.config = SimConfig.from_values(declare_parameters(self, SIM_PARAMETERS))
        from reflexarm.robots import load_robot
        from reflexarm.ros.scenarios import scenario
        from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise

        self.robot = load_robot(cfg.robot)
        setup = scenario(cfg.scene, self.robot)
        noise = PAPER_NOISE if cfg.noise else SensorNoise.none()
        self.plant = Plant(self.robot, scene=setup.scene, noise=noise, seed=cfg.seed, control_period=1.0 / cfg.rate)
        self.plant.reset(setup.trajectory.sample(0.0).q_d)
        self.n = self.robot.n
        self.period_ns = int(round(1e9 / cfg.rate))
        self._tau = np.zeros(self.n)
        self.commands = self.rejected = self.lockstep_timeouts = self.overruns = self.ticks = 0
        self._rejected_text = ""
        self.error = ""
        self.done = False
        out = reliable(10)
        self.pub_js = self.create_publisher(JointState, cfg.joint_states_topic, out)
        self.pub_wrench = self.create_publisher(WrenchStamped, cfg.wrench_topic, out)
        self.create_subscription(Float64MultiArray, cfg.command_topic, self._on_command, reliable(10))
        self._js = JointState()
        self._js.name = list(self.robot.joint_names)
        self._wr = WrenchStamped()
        self._wr.header.frame_id = self.robot.sensor_frame

    def _on_command(self, msg: Float64MultiArray) -> None:
        data = np.asarray(msg.data, dtype=float)
        if data.shape != (self.n,) or not np.all(np.isfinite(data)):
            self.rejected += 1
            text = f"command dropped: {data.size} values (expected {self.n} finite efforts)"
            if text != self._rejected_text:
                self._rejected_text = text
                self.get_logger().warning(text)
            return
        self._tau = data
        self.commands += 1

    def _publish(self, stamp_ns: int) -> None:
        m = self.plant.measure()
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        wr = self._wr
        wr.header.stamp.sec, wr.header.stamp.nanosec = sec, nsec
        f, tq = wr.wrench.force, wr.wrench.torque
        f.x, f.y, f.z, tq.x, tq.y, tq.z = (float(v) for v in m.wrench)
        self.pub_wrench.publish(wr)
        js = self._js
        js.header.stamp.sec, js.header.stamp.nanosec = sec, nsec
        js.position, js.velocity, js.effort = m.q.tolist(), m.dq.tolist(), m.tau_m.tolist()
        self.pub_js.publish(js)

    def _wait_for_peers(self, executor: SingleThreadedExecutor) -> None:
        cfg = self.config
        while not self.done:
            subs = self.count_subscribers(cfg.joint_states_topic)
            pubs = self.count_publishers(cfg.command_topic)
            if subs >= cfg.wait_for_subscribers and (not cfg.lockstep or pubs >= 1):
                return
            executor.spin_once(timeout_sec=0.05)

    def run(self, executor: SingleThreadedExecutor) -> None:
        """Step the plant until ``duration`` of simulated time (or forever), publishing and taking commands."""
        cfg = self.config
        self._wait_for_peers(executor)
        for _ in range(100):  # commands queued before the start (a controller's safe command) are not answers
            executor.spin_once(timeout_sec=0.0)
        self._tau = np.zeros(self.n)
        total = math.inf if cfg.duration == 0 else round(cfg.duration * cfg.rate)
        start = time.time_ns()
        deadline = time.perf_counter()
        while self.ticks < total and not self.done:
            before = self.commands
            self._publish(start + self.ticks * self.period_ns)
            if cfg.lockstep:
                self._await_answer(executor, before)
            else:
                deadline += self.period_ns * 1e-9
                self._pace(executor, deadline)
            try:
                self.plant.step(self._tau)
            except SimulationError as e:  # a diverged plant ends the run, said, not a traceback
                self.get_logger().error(f"the simulation stopped at tick {self.ticks}: {e}")
                self.error = str(e)
                break
            self.ticks += 1
        self.done = True

    def _await_answer(self, executor: SingleThreadedExecutor, before: int) -> None:
        limit = time.monotonic() + self.config.lockstep_timeout
        while self.commands == before:
            executor.spin_once(timeout_sec=0.05)
            if time.monotonic() > limit:
                self.lockstep_timeouts += 1
                if self.lockstep_timeouts == 1:
                    self.get_logger().warning("lockstep: no command within lockstep_timeout; holding the last one")
                return

    def _pace(self, executor: SingleThreadedExecutor, deadline: float) -> None:
        remaining = deadline - time.perf_counter()
        if remaining < 0:
            self.overruns += 1
        while remaining > BUSY_WAIT:
            executor.spin_once(timeout_sec=remaining - BUSY_WAIT)
            remaining = deadline - time.perf_counter()
        while time.perf_counter() < deadline:
            pass
        executor.spin_once(timeout_sec=0.0)

    def summary(self) -> dict[str, Any]:
        """Counts of the run, JSON-ready."""
        return {"ticks": self.ticks, "simulated_s": self.ticks * self.period_ns * 1e-9, "commands": self.commands,
                "rejected_commands": self.rejected, "lockstep_timeouts": self.lockstep_timeouts,
                "overruns": self.overruns, "scene": self.config.scene, "robot": self.robot.name,
                "error": self.error}  # fmt: skip

    def close(self) -> None:
        """Write the summary file, if asked."""
        if self.config.summary_file:
            Path(self.config.summary_file).write_text(json.dumps(self.summary(), indent=1))
