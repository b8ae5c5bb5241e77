"""``reflexarm ros monitor|control``: the Controller live on ``sensor_msgs/JointState``.

Each JointState (mapped by name) is one tick of :class:`reflexarm.control.Controller` (its C++ core):
residual, detection, isolation and force estimate, and in control mode the effort command. What the node
publishes (``~`` is the node's namespace; names are parameters):

- ``~/residual`` (``sensor_msgs/JointState``, residual in ``effort`` [Nm]) every tick;
- ``~/collision_events`` (``diagnostic_msgs/DiagnosticArray``, one status per event: link, force, delays),
  at detection and again when the isolation's estimate is in;
- ``~/contact_wrench`` (``geometry_msgs/WrenchStamped``) and ``~/contact_marker`` (``visualization_msgs/Marker``
  ARROW) when an estimate is in;
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``): the node's state, at once when a fault begins or ends
  and every second;
- control mode: ``command_topic`` (``std_msgs/Float64MultiArray``, ros2_control's forward command controller).

Faults are never silence: a JointState whose names do not match the robot, with a missing field, NaN or
implausible values, a stamp out of order or jumping, a topic that goes silent (``joint_state_timeout``,
``wrench_timeout``), a publisher of the wrong type on an input topic, a jump of the ROS clock: each is an ERROR
status naming it, a log line, and in control mode the contract's safe command (gravity compensation at the last
accepted posture, zero before the first). The node stays up; the next good JointState is a normal tick, so
detection goes on (a fault never switches it off).
"""

from __future__ import annotations

import json
import math
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rclpy.subscription import MessageInfo
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty, Float64MultiArray
from visualization_msgs.msg import Marker

from reflexarm.ros import outputs
from reflexarm.ros._node_tools import declare_parameters, reliable
from reflexarm.ros.config import MONITOR_PARAMETERS, MonitorConfig
from reflexarm.ros.controller_setup import build_controller, load_models
from reflexarm.ros.coverage_watch import CoverageWatch
from reflexarm.ros.event_tracker import EventTracker
from reflexarm.ros.inputs import JointStateReader, StampClock, stamp_ns
from reflexarm.ros.latency import LatencyLog
from reflexarm.ros.references import ReferenceSource
from reflexarm.signals import Measurement, Reference

__all__ = ["CollisionMonitor"]

#: A JointState waiting for the wrench of its own stamp is handled with the last wrench after this long [s].
SYNC_WAIT = 0.002
#: JointStates taken at most in one callback after the one the executor handed over.
DRAIN_MAX = 100
#: Publisher types on the input topics are checked this often [s].
TYPE_CHECK_PERIOD = 0.5


class CollisionMonitor(Node):
    """The collision node (see the module docstring). ``mode``: "monitor" or "control"; the other settings are
    ROS parameters (:data:`~reflexarm.ros.config.MONITOR_PARAMETERS`), from ``parameter_overrides`` or a YAML
    file given in ``cli_args`` (``["--ros-args", "--params-file", path]``)."""

    def __init__(self, mode: str, *, name: str | None = None, **node_kwargs: Any) -> None:
        super().__init__(name or f"reflexarm_{mode}", **node_kwargs)
        cfg = self.config = MonitorConfig.from_values(mode, declare_parameters(self, MONITOR_PARAMETERS))
        self.robot, model = load_models(cfg)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            self.controller = build_controller(cfg, model)
        for w in caught:  # model-file and threshold warnings go to the node's log
            self.get_logger().warning(str(w.message))
        self.n = n = model.n
        self.joint_names = list(model.joint_names)
        self.base_frame = model.frame_names[1] if len(model.frame_names) > 1 else "world"
        self._gravity = np.asarray(model.gravity, dtype=float).copy()
        self._zero_wrench = np.zeros(6)
        self._wrench = self._zero_wrench
        self._wrench_ns: int | None = None
        self._zeros = np.zeros(n)
        self.reader = JointStateReader(self.joint_names, cfg.joint_states_topic)
        self._residual_msg = outputs.residual_state(Time(), self.joint_names, self._zeros)
        self.stamps = StampClock(cfg.max_stamp_gap, cfg.joint_states_topic)
        self.reference = ReferenceSource(cfg, model)
        self.faults: dict[str, str] = {}
        self.fault_counts: dict[str, int] = {}
        self.fault_first: dict[str, str] = {}
        self.latency = LatencyLog()
        self.done = False
        self._q_safe: np.ndarray | None = None
        self._pending: tuple[JointState, MessageInfo, float] | None = None
        self._last_js: float | None = None  # monotonic [s] of the last message
        self._last_wrench: float | None = None
        self._start = time.monotonic()
        self._ticks = self._lost = 0
        self.heard = 0  # JointState messages received
        self._last_type_check = 0.0
        self._last_diag = 0.0
        self.coverage = CoverageWatch.from_threshold(cfg.threshold, n)
        if self.coverage is None:
            self.get_logger().warning(
                "no coverage stored with the levels (a thresholds.json of tune-thresholds has it): motions outside "
                "what they were tuned on are not flagged"
            )
        self.recorder = self._make_recorder()
        self._make_interfaces()
        self.tracker = EventTracker(self.controller, {"events": self.pub_events, "wrench": self.pub_wrench,
                                    "marker": self.pub_marker}, node=self.get_name(), hardware_id=self.robot.name,
                                    frame=self.base_frame)  # fmt: skip

    def _make_recorder(self) -> Any:
        if not self.config.record_bag:
            return None
        from reflexarm.ros.bag_recorder import BagRecorder

        topics = {self.config.joint_states_topic: "sensor_msgs/msg/JointState"}
        if self.config.wrench_topic:
            topics[self.config.wrench_topic] = "geometry_msgs/msg/WrenchStamped"
        return BagRecorder(self.config.record_bag, topics)

    def _make_interfaces(self) -> None:
        cfg, depth = self.config, reliable(self.config.qos_depth)
        out = reliable(10)
        self.pub_residual = self.create_publisher(JointState, "~/residual", out)
        self.pub_events = self.create_publisher(DiagnosticArray, "~/collision_events", out)
        self.pub_wrench = self.create_publisher(WrenchStamped, "~/contact_wrench", out)
        self.pub_marker = self.create_publisher(Marker, "~/contact_marker", out)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(1))
        self.pub_command = (
            self.create_publisher(Float64MultiArray, cfg.command_topic, out) if cfg.mode == "control" else None
        )
        # the wrench subscription first: with both ready in one wait, the wrench of a tick is taken before its
        # JointState
        if cfg.wrench_topic:
            self.create_subscription(WrenchStamped, cfg.wrench_topic, self._on_wrench, depth)
        self._js_sub = self.create_subscription(JointState, cfg.joint_states_topic, self._on_joint_state, depth)
        if cfg.mode == "control" and cfg.reference == "topic":
            self.create_subscription(JointState, cfg.reference_topic, self.reference.on_message, out)
        self.create_subscription(Empty, "~/reset", self._on_reset, out)
        self.create_timer(cfg.watchdog_period, self._watchdog)
        threshold = JumpThreshold(
            min_forward=Duration(nanoseconds=int(cfg.max_stamp_gap * 1e9)), min_backward=Duration(nanoseconds=-1)
        )
        self._jump_handle = self.get_clock().create_jump_callback(threshold, post_callback=self._on_clock_jump)

    # ------------------------------------------------------------------ faults
    def _set_fault(self, key: str, text: str) -> None:
        self.fault_counts[key] = self.fault_counts.get(key, 0) + 1
        if self.faults.get(key) != text:
            self.fault_first.setdefault(key, text)
            self.faults[key] = text
            self.get_logger().error(text)
            self._publish_diagnostics()

    def _clear_fault(self, key: str) -> None:
        if self.faults.pop(key, None) is not None:
            self.get_logger().info(f"fault cleared: {key}")
            self._publish_diagnostics()

    def _safe_command(self) -> np.ndarray:
        """The contract's safe command: gravity compensation at the last accepted posture (zero before it)."""
        if self._q_safe is None:
            return self._zeros.copy()
        tau = self.controller.robot.compute_gravity(self._q_safe)
        limit = self.controller.torque_limit
        return np.clip(tau, -limit, limit) if limit is not None else tau

    def _publish_safe(self) -> None:
        if self.pub_command is not None:
            self.pub_command.publish(outputs.effort_command(self._safe_command()))

    def _publish_diagnostics(self) -> None:
        self._last_diag = time.monotonic()
        status = DiagnosticStatus()
        status.name = f"{self.get_name()}: collision monitor"
        status.hardware_id = self.robot.name
        if self.faults:
            status.level = outputs.LEVEL_ERROR
            status.message = "; ".join(self.faults.values())
        elif self.coverage is not None and self.coverage.warned:
            status.level = outputs.LEVEL_WARN
            status.message = "; ".join(self.coverage.warned.values())
        else:
            status.level = outputs.LEVEL_OK
            status.message = f"{self.config.mode}: ok"
        values = {"ticks": self._ticks, "events": len(self.tracker.events), "lost_by_stamp": self._lost,
                  "detection": "on" if self.controller.detector is not None else "off"}  # fmt: skip
        values.update({f"faults_{k}": v for k, v in self.fault_counts.items()})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status]
        self.pub_diag.publish(msg)

    # ------------------------------------------------------------------ inputs
    def _on_wrench(self, msg: WrenchStamped, info: MessageInfo) -> None:
        f, m = msg.wrench.force, msg.wrench.torque
        self._wrench = np.array([f.x, f.y, f.z, m.x, m.y, m.z])
        self._wrench_ns = stamp_ns(msg.header.stamp)
        self._last_wrench = time.monotonic()
        self._clear_fault("wrench_stale")
        if self.recorder is not None:
            self.recorder.put(self.config.wrench_topic, serialize_message(msg), info["received_timestamp"])
        pending = self._pending
        if pending is not None and self._wrench_ns >= stamp_ns(pending[0].header.stamp):
            self._pending = None
            self._tick(pending[0], pending[1])

    def _on_joint_state(self, msg: JointState, info: MessageInfo) -> None:
        """A JointState, and then those already waiting behind it (taken here, without a round through the
        executor's wait set per message: catching up after a stall costs a fraction of falling behind)."""
        self._on_one_joint_state(msg, info)
        handle = self._js_sub.handle
        for _ in range(DRAIN_MAX):
            with handle:
                taken = handle.take_message(JointState, False)
            if taken is None:
                return
            self._on_one_joint_state(taken[0], taken[1])

    def _on_one_joint_state(self, msg: JointState, info: MessageInfo) -> None:
        self._last_js = now = time.monotonic()
        self.heard += 1
        if "joint_state_stale" in self.faults:
            self._clear_fault("joint_state_stale")
        if self.recorder is not None:
            self.recorder.put(self.config.joint_states_topic, serialize_message(msg), info["received_timestamp"])
        if self._pending is not None:  # a newer JointState: the waiting one goes with the wrench there is
            pending, self._pending = self._pending, None
            self._tick(pending[0], pending[1])
        if self.config.wrench_topic and (self._wrench_ns is None or self._wrench_ns < stamp_ns(msg.header.stamp)):
            if self._wrench_ns is not None:  # wait (briefly) for the wrench of this stamp
                self._pending = (msg, info, now)
                return
        self._tick(msg, info)

    def _on_reset(self, _msg: Empty) -> None:
        self.get_logger().warning("reset requested on ~/reset: controller, clock and faults re-initialised")
        self._rearm(clear_clock=True)
        self.faults.pop("clock", None)
        self._publish_diagnostics()

    def _on_clock_jump(self, jump: Any) -> None:
        delta = jump.delta.nanoseconds * 1e-9
        self._set_fault("ros_clock", f"ROS clock jumped by {delta:+.6f} s ({jump.clock_change})")

    # ------------------------------------------------------------------ the tick
    def _tick(self, msg: JointState, info: MessageInfo) -> None:
        """One controller tick on one JointState (or the safe command and a fault naming what is wrong)."""
        started = time.time_ns()
        ns = stamp_ns(msg.header.stamp)
        read = self.reader.read(msg)
        if isinstance(read, str):
            self._reject("joint_state", read)
            return
        q, dq, tau_m = read
        last = self.stamps.last_ns
        t, jump = self.stamps.check(ns)
        if jump:
            self._on_stamp_jump(jump, ns, last)
            return
        if last is not None and ns > last:
            self._lost += max(0, round((ns - last) * 1e-9 / self.controller.dt) - 1)
        if self.config.wrench_topic and self._wrench_ns is None:
            self._reject("wrench_stale", f"no WrenchStamped received on {self.config.wrench_topic} yet")
            return
        ref = self.reference.sample(t, q) if self.config.mode == "control" else Reference(q, self._zeros, self._zeros)
        cmd = self.controller.step(Measurement(t, q, dq, tau_m, self._wrench, self._gravity), ref)
        self._ticks += 1
        if cmd.fault:
            self._set_fault("input", f"JointState on {self.config.joint_states_topic}: {cmd.fault}")
        else:
            self._q_safe = q
            self._clear_fault("input")
            if self.coverage is not None:
                for line in self.coverage.check(t, q, dq):
                    self.get_logger().warning(line)
                    self._publish_diagnostics()
            for key in ("joint_state", "clock", "ros_clock"):
                self._clear_fault(key)
        if self.pub_command is not None:
            tau = self._safe_command() if self.faults and not cmd.fault else cmd.tau
            self.pub_command.publish(outputs.effort_command(tau))
        self.pub_residual.publish(outputs.residual_state(msg.header.stamp, self.joint_names, cmd.residual,
                                                         self._residual_msg))  # fmt: skip
        event_published = self._follow_event(t, cmd.residual, cmd.collision, msg)
        self.latency.add(info["received_timestamp"], started, time.time_ns(), event_published)

    def _reject(self, key: str, text: str) -> None:
        self._set_fault(key, text)
        self._publish_safe()

    def _on_stamp_jump(self, text: str, ns: int, last: int | None) -> None:
        self._reject("clock", text)
        if last is not None and ns < last and self.config.mode == "monitor":
            self.get_logger().warning("monitor: re-initialised on the new time line after the clock jump back")
            self._rearm(clear_clock=True)

    # ------------------------------------------------------------------ events
    def _follow_event(self, t: float, residual: np.ndarray, collision: bool, msg: JointState) -> bool:
        """Publish a new event at once, its estimate when it is in; re-arm the monitor. True: an event was sent."""
        published = self.tracker.follow(t, residual, collision, msg.header.stamp, self.stamps.first_ns or 0)
        cfg = self.config
        if self.tracker.open and cfg.mode == "monitor" and cfg.rearm_after > 0:
            if t - self.tracker.t_below >= cfg.rearm_after:
                self._rearm(clear_clock=False)
        return published

    def _rearm(self, *, clear_clock: bool) -> None:
        self.controller.reset()
        if clear_clock:
            self.stamps.reset()
            self.reference.reset()
        self.tracker.close(self.get_clock().now().to_msg())

    # ------------------------------------------------------------------ watchdog
    def _watchdog(self) -> None:
        """Stale or missing inputs, publishers of the wrong type, a JointState waiting too long for its wrench,
        and the periodic diagnostics."""
        now = time.monotonic()
        cfg = self.config
        if self._pending is not None and now - self._pending[2] > SYNC_WAIT:
            pending, self._pending = self._pending, None
            self._tick(pending[0], pending[1])
        stale = _staleness(cfg.joint_states_topic, "JointState", self._last_js, self._start, now,
                           cfg.joint_state_timeout)  # fmt: skip
        if stale:
            self._reject("joint_state_stale", stale)
        else:
            self._clear_fault("joint_state_stale")
        if cfg.wrench_topic:
            stale = _staleness(cfg.wrench_topic, "WrenchStamped", self._last_wrench, self._start, now,
                               cfg.wrench_timeout)  # fmt: skip
            if stale:
                self._reject("wrench_stale", stale)
        if now - self._last_type_check > TYPE_CHECK_PERIOD:
            self._last_type_check = now
            self._check_types()
        if now - self._last_diag > 1.0:
            self._publish_diagnostics()

    def _check_types(self) -> None:
        expected = {self.config.joint_states_topic: "sensor_msgs/msg/JointState"}
        if self.config.wrench_topic:
            expected[self.config.wrench_topic] = "geometry_msgs/msg/WrenchStamped"
        for topic, want in expected.items():
            wrong = [f"{p.node_name} ({p.topic_type})" for p in self.get_publishers_info_by_topic(topic)
                     if p.topic_type != want]  # fmt: skip
            key = f"type {topic}"
            if wrong:
                self._set_fault(key, f"wrong message type on {topic}: publishers {wrong}; expected {want}")
            else:
                self._clear_fault(key)

    # ------------------------------------------------------------------ end
    def summary(self) -> dict[str, Any]:
        """Ticks, events, faults (first text and count per kind) and latencies, JSON-ready."""
        return {
            "mode": self.config.mode,
            "robot": self.robot.name,
            "heard": self.heard,
            "joint_states": self._ticks,
            "lost_by_stamp": self._lost,
            "first_stamp_ns": self.stamps.first_ns,
            "events": self.tracker.events,
            "faults": {k: {"first": self.fault_first.get(k, ""), "count": c} for k, c in self.fault_counts.items()},
            "active_faults": dict(self.faults),
            "outside_coverage": [] if self.coverage is None else list(self.coverage.warned.values()),
            "latency": self.latency.summary(),
            "bag": None if self.recorder is None else {"path": str(self.recorder.path), "count": self.recorder.count},
        }

    def close(self) -> None:
        """A last safe command (control mode), the bag closed, the summary written."""
        try:
            self._publish_safe()
        except Exception:  # noqa: BLE001 - the context may be gone already
            pass
        if self.recorder is not None:
            self.recorder.close()
        if self.config.summary_file:
            Path(self.config.summary_file).write_text(json.dumps(self.summary(), indent=1, default=_json_default))


def _staleness(topic: str, kind: str, last: float | None, start: float, now: float, timeout: float) -> str:
    if last is None:
        waited = now - start
        return f"no {kind} received on {topic} yet ({waited:.2f} s)" if waited > timeout else ""
    age = now - last
    return f"{kind} on {topic} silent for {age:.3f} s (timeout {timeout:g} s)" if age > timeout else ""


def _json_default(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
