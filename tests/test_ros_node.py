"""The ROS 2 nodes (``reflexarm ros monitor|control|sim``) over real DDS, in a private network namespace.

Every test that starts DDS re-executes itself under ``unshare -n`` (a namespace whose only interface is
loopback, brought up with ``ip link set lo up``) with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``: no test sends
anything beyond loopback. Where ``unshare`` is not permitted those tests skip, saying so. Waits are bounded
(a test fails rather than hangs) but nothing asserts on time: ticks are compared by their stamps.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="the 'ros' extra (rclpy) is not installed")

INSIDE = "REFLEXARM_TEST_NETNS"


@functools.cache
def _unshare_reason() -> str:
    """Why a private network namespace cannot be made here ('' when it can)."""
    try:
        res = subprocess.run(["unshare", "-n", "ip", "link", "set", "lo", "up"], capture_output=True, text=True)
    except FileNotFoundError as e:
        return f"unshare / ip not found ({e})"
    return "" if res.returncode == 0 else f"unshare -n not permitted here: {res.stderr.strip()}"


def inside_private_network(request: pytest.FixtureRequest, timeout: float = 300.0) -> bool:
    """True inside the namespace (run the body). Outside: re-run this very test under ``unshare -n`` and return
    False once it passed there (fail with its output if it did not; skip where unshare is not permitted)."""
    if os.environ.get(INSIDE) == "1":
        links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True, check=True).stdout
        names = [line.split(":")[1].strip() for line in links.splitlines() if line.strip()]
        assert names == ["lo"], f"the test's namespace must have loopback only; found {names}"
        return True
    reason = _unshare_reason()
    if reason:
        pytest.skip(f"ROS 2 tests run only in a loopback-only network namespace, and {reason}")
    root = Path(__file__).resolve().parents[1]
    inner = (
        f"ip link set lo up && exec env {INSIDE}=1 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
        f"{sys.executable} -m pytest -q -x -p no:cacheprovider -p no:randomly --show-capture=no --tb=short "
        f"'{request.node.nodeid}'"
    )
    res = subprocess.run(["unshare", "-n", "bash", "-c", inner], cwd=root, capture_output=True, text=True,
                         timeout=timeout)  # fmt: skip
    tail = (res.stdout + res.stderr)[-6000:]
    assert res.returncode == 0, f"the test failed inside its network namespace:\n{tail}"
    assert " passed" in res.stdout, f"the test did not run inside its network namespace:\n{tail}"
    return False


# ---------------------------------------------------------------------- no DDS: the edge's checks
def test_joint_state_reader_maps_by_name_and_names_what_is_wrong():
    from types import SimpleNamespace

    from reflexarm.ros.inputs import JointStateReader

    reader = JointStateReader(["a", "b", "c"], "/joint_states")
    msg = SimpleNamespace(name=["c", "gripper", "a", "b"], position=[3.0, 9.0, 1.0, 2.0], velocity=[0.3, 9, 0.1, 0.2],
                          effort=[30.0, 9, 10.0, 20.0])  # fmt: skip
    q, dq, tau = reader.read(msg)
    np.testing.assert_array_equal(q, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(dq, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(tau, [10.0, 20.0, 30.0])
    bad = reader.read(SimpleNamespace(name=["a", "x", "c"], position=[0] * 3, velocity=[0] * 3, effort=[0] * 3))
    assert bad == (
        "JointState on /joint_states: names do not match the robot's joints: missing ['b']; received ['a', 'x', 'c'] "
        "(unknown ['x']); expected ['a', 'b', 'c']"
    )
    short = reader.read(SimpleNamespace(name=["a", "b", "c"], position=[0] * 3, velocity=[], effort=[0] * 3))
    assert short == (
        "JointState on /joint_states: velocity has 0 values for 3 names (position, velocity, effort are needed "
        "for every joint)"
    )


def test_stamp_clock_reports_jumps_once_and_keeps_exact_periods():
    from reflexarm.ros.inputs import StampClock

    clock = StampClock(0.1, "/joint_states")
    base = 1_795_000_000_123_456_789
    assert clock.check(base) == (0.0, "")
    t, fault = clock.check(base + 1_000_000)
    assert (t, fault) == (0.001, "")
    t, fault = clock.check(base + 2_001_000_000)
    assert fault == "clock jump on /joint_states: stamp 2.000000 s past the last one (more than max_stamp_gap = 0.1 s)"
    assert clock.check(base + 2_002_000_000)[1] == ""  # the new time line is accepted
    assert "1.002000 s before the last one (a clock reset?" in clock.check(base + 1_000_000_000)[1]


def test_without_the_ros_extra_the_command_says_what_to_install():
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "from reflexarm.cli import main\n"
        "sys.exit(main(['ros', 'monitor']))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 2
    assert "reflexarm ros: error: reflexarm ros needs the 'ros' extra" in res.stderr
    assert "pip install 'reflexarm[ros]'" in res.stderr


def test_parameter_overrides_are_typed_and_checked():
    from reflexarm._cli.ros import parse_overrides
    from reflexarm.errors import ConfigError
    from reflexarm.ros.config import MONITOR_PARAMETERS, SIM_PARAMETERS, MonitorConfig, SimConfig, parameter_names

    assert parameter_names(MonitorConfig) == ["mode"] + [name for name, _, _ in MONITOR_PARAMETERS]
    assert parameter_names(SimConfig) == [name for name, _, _ in SIM_PARAMETERS]

    values = parse_overrides(["threshold:=20", "observer_gain:=7", "rearm_after:=0.5"], MONITOR_PARAMETERS)
    assert values == {"threshold": "20", "observer_gain": 7.0, "rearm_after": 0.5}
    with pytest.raises(ConfigError, match="parameter observer_gain must be a float; got 'fast'"):
        parse_overrides(["observer_gain:=fast"], MONITOR_PARAMETERS)
    with pytest.raises(ConfigError, match="unknown parameter 'gain'; parameters are: "):
        parse_overrides(["gain:=5"], MONITOR_PARAMETERS)
    with pytest.raises(ConfigError, match="parameter reaction must be one of gravity, brake, retract"):
        MonitorConfig.from_values("control", {"reaction": "stop"})


# ---------------------------------------------------------------------- over DDS, in-process nodes
class _Harness:
    """A CollisionMonitor and a test node (publishers of its inputs, listeners of its outputs) on one executor."""

    def __init__(self, mode: str, cli_args: list[str] | None = None, **params: object) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from reflexarm.ros._node_tools import reliable
        from reflexarm.ros.monitor_node import CollisionMonitor

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = CollisionMonitor(mode, context=self.ctx, parameter_overrides=overrides, cli_args=cli_args)
        self.peer = rclpy.create_node("test_peer", context=self.ctx)
        self.pub = self.peer.create_publisher(JointState, "/joint_states", reliable(50))
        self.commands: list[np.ndarray] = []
        self.events: list[object] = []
        self.peer.create_subscription(Float64MultiArray, self.node.config.command_topic,
                                      lambda m: self.commands.append(np.array(m.data)), reliable(50))  # fmt: skip
        self.peer.create_subscription(DiagnosticArray, "/reflexarm_" + mode + "/collision_events",
                                      lambda m: self.events.extend(m.status), reliable(10))  # fmt: skip
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.robot = self.node.controller.robot
        self.names = list(self.robot.joint_names)
        from reflexarm.experiments.collision import EE_START

        self.q = EE_START.copy()
        self.tau = self.robot.compute_gravity(self.q)
        self.ns = 1_795_000_000_000_000_000
        self.spin_until(lambda: self.peer.count_subscribers("/joint_states") >= 1, "the node's subscription")

    def spin_until(self, cond, what: str, limit: float = 20.0) -> None:
        end = time.monotonic() + limit
        while not cond():
            assert time.monotonic() < end, f"waited {limit:g} s for {what}"
            self.executor.spin_once(timeout_sec=0.01)

    def send(self, *, names=None, q=None, dq=None, tau=None, step_ns: int = 1_000_000) -> None:
        from sensor_msgs.msg import JointState

        self.ns += step_ns
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(self.ns, 1_000_000_000)
        msg.name = self.names if names is None else names
        n = len(msg.name)
        msg.position = list(self.q if q is None else q)[:n]
        msg.velocity = [0.0] * n if dq is None else list(dq)
        msg.effort = list(self.tau if tau is None else tau)[:n]
        seen = self.node.heard
        self.pub.publish(msg)
        self.spin_until(lambda: self.node.heard > seen, "the tick")

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.close()
        self.node.destroy_node()
        self.peer.destroy_node()
        rclpy.shutdown(context=self.ctx)


def test_bad_input_is_a_fault_naming_it_the_node_lives_and_detection_goes_on(request):
    if not inside_private_network(request):
        return
    h = _Harness("monitor", joint_state_timeout=0.2, rearm_after=0.05)
    try:
        for _ in range(20):
            h.send()
        assert h.node.faults == {} and h.node.tracker.events == []
        h.send(names=[*h.names[:6], "l_arm_gripper"])  # a joint named wrong
        assert "missing ['l_arm_wry2']" in h.node.faults["joint_state"]
        assert "(unknown ['l_arm_gripper'])" in h.node.faults["joint_state"]
        q = h.q.copy()
        q[2] = np.nan
        h.send(q=q)  # NaN
        assert "JointState on /joint_states: " in h.node.faults["input"]
        assert "q" in h.node.faults["input"] and "nan" in h.node.faults["input"].lower()
        h.send()
        assert "input" not in h.node.faults and "joint_state" not in h.node.faults  # the next good tick clears them
        h.send(step_ns=-500_000)  # a stamp before the last one
        assert "t" in h.node.faults["input"] and "input" in h.node.fault_first
        h.send(step_ns=1_500_000)
        h.send(step_ns=3_000_000_000)  # the clock jumps 3 s
        assert h.node.fault_first["clock"].startswith("clock jump on /joint_states: stamp 3.000000 s past")
        h.send()
        assert "clock" not in h.node.faults
        # a topic that goes silent, then a publisher of the wrong type on it
        h.spin_until(lambda: "joint_state_stale" in h.node.faults, "the staleness fault")
        assert "JointState on /joint_states silent for" in h.node.faults["joint_state_stale"]
        import rclpy
        from std_msgs.msg import String

        other = rclpy.Context()  # a participant of its own (one participant cannot have two types on a topic)
        rclpy.init(context=other)
        stranger = rclpy.create_node("stranger", context=other)
        stranger.create_publisher(String, "/joint_states", 10)
        try:
            h.spin_until(lambda: "type /joint_states" in h.node.faults, "the wrong-type fault")
        finally:
            stranger.destroy_node()
            rclpy.shutdown(context=other)
        text = h.node.faults["type /joint_states"]  # the node's name may not be discovered yet: _NODE_NAME_UNKNOWN_
        assert text.startswith("wrong message type on /joint_states: publishers ['"), text
        assert text.endswith(" (std_msgs/msg/String)']; expected sensor_msgs/msg/JointState"), text
        # detection after all that: 30 Nm on joint 2 at rest is detected and published as an event
        h.send(step_ns=10_000_000)
        for _ in range(400):
            h.send(tau=h.tau + np.array([0, 30.0, 0, 0, 0, 0, 0]))
            if h.node.tracker.events:
                break
        assert len(h.node.tracker.events) == 1, "no collision detected after the faults"
        event = h.node.tracker.events[0]
        assert event["joints"] == [1] and event["contact_class"] == "collision"
        h.spin_until(lambda: len(h.events) >= 1, "the event on ~/collision_events")
        status = h.events[0]
        assert status.name == "reflexarm_monitor: collision 1" and status.level == b"\x02"
        values = {kv.key: kv.value for kv in status.values}
        assert values["joints"] == "2" and float(values["delay_s"]) > 0
        assert {"link", "force_N", "delay_s", "estimate_delay_s", "stamp_ns"} <= set(values)
        assert h.node.faults.get("joint_state_stale") is None
    finally:
        h.close()


def test_control_mode_sends_the_safe_command_on_faults(request, tmp_path):
    if not inside_private_network(request):
        return
    bag = tmp_path / "heard"
    yaml = tmp_path / "params.yaml"  # ROS 2's layout; -p overrides (here: record_bag) win over the file
    yaml.write_text("/**:\n  ros__parameters:\n    joint_state_timeout: 30.0\n    threshold: '12,12,12,12,9,9,9'\n"
                    "    reaction: brake\n    record_bag: ignored\n")  # fmt: skip
    h = _Harness("control", ["--ros-args", "--params-file", str(yaml)], record_bag=str(bag))
    try:
        assert (h.node.config.joint_state_timeout, h.node.config.reaction) == (30.0, "brake")
        assert h.node.controller.detector.threshold.tolist() == [12, 12, 12, 12, 9, 9, 9]
        assert h.node.config.record_bag == str(bag)
        for _ in range(5):
            h.send()
        h.spin_until(lambda: len(h.commands) >= 5, "five commands")
        assert all(c.shape == (7,) and np.all(np.isfinite(c)) for c in h.commands)
        h.send(names=h.names[::-1][:6])  # wrong names: the safe command, gravity at the last accepted posture
        h.spin_until(lambda: len(h.commands) >= 6, "the safe command")
        limit = h.node.controller.torque_limit
        expected = np.clip(h.robot.compute_gravity(h.q), -limit, limit)
        np.testing.assert_allclose(h.commands[-1], expected, atol=1e-12, err_msg="the safe command is g(q_last)")
        q = h.q.copy()
        q[0] = np.inf
        h.send(q=q)
        h.spin_until(lambda: len(h.commands) >= 7, "the safe command")
        np.testing.assert_allclose(h.commands[-1], expected, atol=1e-9, err_msg="the contract's safe command")
    finally:
        h.close()
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        assert [c.topic for c in reader.connections] == ["/joint_states"]
        assert reader.message_count == 7  # everything heard, the bad messages too


# ---------------------------------------------------------------------- the whole loop, two processes
@pytest.mark.slow
def test_demo_collision_over_dds_is_detected_at_the_in_process_tick(request, tmp_path):
    if not inside_private_network(request):
        return
    from reflexarm.experiments.collision import EE_SETTINGS, run_ee_collision

    trace = run_ee_collision(EE_SETTINGS[2])  # the demo's Coll.Det run, in process (the compiled loop)
    k_ref = int(np.argmax(trace.collision))
    assert trace.collision[k_ref]
    cli = [sys.executable, "-m", "reflexarm.cli", "ros"]
    control = subprocess.Popen(
        [*cli, "control", "-p", "reference:=demo", "-p", "model_error:=0.1",
         "-p", "wrench_topic:=/reflexarm_sim/wrench", "-p", "joint_state_timeout:=30.0",
         "-p", "wrench_timeout:=30.0", "-p", f"summary_file:={tmp_path}/ctrl.json"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        sim = subprocess.run(
            [*cli, "sim", "-p", "lockstep:=true", "-p", "lockstep_timeout:=30.0", "--duration", f"{k_ref / 1000 + 0.1}",
             "-p", f"summary_file:={tmp_path}/sim.json"],
            capture_output=True, text=True, timeout=240,
        )  # fmt: skip
    finally:
        control.terminate()
        out, _ = control.communicate(timeout=60)
    assert sim.returncode == 0, sim.stdout + sim.stderr
    ran = json.loads((tmp_path / "sim.json").read_text())
    assert ran["lockstep_timeouts"] == 0 and ran["rejected_commands"] == 0, ran
    summary = json.loads((tmp_path / "ctrl.json").read_text())
    assert summary["faults"] == {}, summary["faults"]
    assert summary["joint_states"] == ran["ticks"] and summary["lost_by_stamp"] == 0
    assert len(summary["events"]) == 1, out
    event = summary["events"][0]
    k_dds = round(event["t_detect"] * 1000)
    assert abs(k_dds - k_ref) <= 2, f"detected at tick {k_dds} over DDS, {k_ref} in process"
    assert event["contact_class"] == trace.meta["collision_event"]["contact_class"] == "contact"
    assert event["estimate"]["link_name"] == trace.meta["collision_event"]["estimate"]["link_name"]


def test_the_simulated_robot_runs_in_real_time_and_is_heard(request, tmp_path):
    if not inside_private_network(request):
        return
    cli = [sys.executable, "-m", "reflexarm.cli", "ros"]
    monitor = subprocess.Popen(
        [*cli, "monitor", "-p", "joint_state_timeout:=30.0", "-p", f"summary_file:={tmp_path}/monitor.json"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        sim = subprocess.run([*cli, "sim", "-p", "scene:=none", "-p", f"summary_file:={tmp_path}/sim.json",
                              "--duration", "0.5"], capture_output=True, text=True, timeout=240)  # fmt: skip
        time.sleep(1.0)  # the last messages on their way (not a timing assertion: counts are compared below)
    finally:
        monitor.terminate()
        out, _ = monitor.communicate(timeout=60)
    assert sim.returncode == 0, sim.stdout + sim.stderr
    assert "sim: 500 ticks (0.500 s)" in sim.stdout
    ran = json.loads((tmp_path / "sim.json").read_text())
    heard = json.loads((tmp_path / "monitor.json").read_text())
    assert ran["ticks"] == 500 and ran["commands"] == 0  # nobody commands: the plant holds zero effort
    assert 0 < heard["heard"] <= 500, out  # the arm falls (no command): its faults are the contract's business
