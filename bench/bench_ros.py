"""The collision node over DDS: lost messages at 1 kHz, and the latency from a JointState's arrival to the
publication of the tick's outputs (the event's on a detecting tick), median and p99.

Runs itself in a private network namespace (``unshare -n``, loopback only, ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST``): nothing leaves the machine. A publisher (this process) sends ``sensor_msgs/JointState`` of the Atlas
arm at rest at 1 kHz (sleeping, then busy-waiting the last 0.2 ms of each period) for ``SECONDS`` s, with a
30 Nm step on joint 2 for 0.3 s of every second; ``reflexarm ros monitor`` (another process, re-arming 0.3 s
after the residual fell below the threshold) detects each step and publishes an event. The baseline, measured
in the same run, is a bare rclpy echo node on the same stream (10 s; arrival to the publication of a
Float64MultiArray): the floor of rclpy and DDS on this machine.

Twice: the node on the normal scheduler, then with ``--realtime-priority 50`` (SCHED_FIFO, as ros2_control runs
its loop). Goal (issue 17): 0 lost messages; latency median <= 1 ms, p99 <= 5 ms on the 2-core machine.
``python bench/bench_ros.py [SECONDS]`` (default 60).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

INSIDE = "REFLEXARM_BENCH_NETNS"
ROOT = Path(__file__).resolve().parents[1]
SECONDS = 60.0
PULSE = (0.3, 1.0, 30.0)  # [s] on, [s] period, [Nm] on joint 2
DEPTH = 1000  # history of the publisher and of the node's subscription: 1 s at 1 kHz, a backlog rather than a loss
SLEEP_MARGIN = 0.0002  # the publisher busy-waits only this last part of a period [s]
#: SCHED_FIFO priority of the node (``--realtime-priority``; 0: the normal scheduler), from $BENCH_ROS_REALTIME
REALTIME = int(os.environ.get("BENCH_ROS_REALTIME", "0"))
PRIORITIES = (0, 50)


def _echo() -> None:
    """The baseline node: JointState in, Float64MultiArray out, latencies (reception -> published) to a file."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from reflexarm.ros._node_tools import reliable

    rclpy.init(args=[])
    node = rclpy.create_node("echo")
    pub = node.create_publisher(Float64MultiArray, "/echo", reliable(10))
    lat: list[int] = []

    def cb(msg: JointState, info: dict) -> None:
        out = Float64MultiArray()
        out.data = list(msg.effort)
        pub.publish(out)
        lat.append(time.time_ns() - info["received_timestamp"])

    node.create_subscription(JointState, "/joint_states", cb, reliable(DEPTH))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while True:
            executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        Path(sys.argv[2]).write_text(json.dumps({"heard": len(lat), "latency_ns": lat}))


def _publish(seconds: float, subscriber: str) -> dict[str, float]:
    """Send JointState at 1 kHz for ``seconds`` once ``subscriber`` listens; sent count and achieved rate."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from reflexarm.experiments.collision import EE_START
    from reflexarm.robots import load_robot
    from reflexarm.ros._node_tools import reliable

    robot = load_robot("atlas_v5_left_arm")
    tau = robot.compute_gravity(EE_START)
    rclpy.init(args=[])
    node = rclpy.create_node("bench_publisher")
    pub = node.create_publisher(JointState, "/joint_states", reliable(DEPTH))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    end = time.monotonic() + 60
    while not any(i.node_name == subscriber for i in node.get_subscriptions_info_by_topic("/joint_states")):
        assert time.monotonic() < end, f"{subscriber} did not subscribe within 60 s"
        executor.spin_once(timeout_sec=0.05)
    time.sleep(2.0)  # discovery settles
    msg = JointState()
    msg.name = list(robot.joint_names)
    msg.position, msg.velocity = EE_START.tolist(), [0.0] * robot.n
    n = round(seconds * 1000)
    start_ns, t0 = time.time_ns(), time.perf_counter()
    for k in range(n):
        wait = t0 + k * 1e-3 - time.perf_counter()
        if wait > SLEEP_MARGIN:  # sleep most of the period: a busy wait would take a whole core from the node
            time.sleep(wait - SLEEP_MARGIN)
        while time.perf_counter() < t0 + k * 1e-3:
            pass
        effort = tau.copy()
        if (k % 1000) < PULSE[0] * 1000:
            effort[1] += PULSE[2]
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(start_ns + k * 1_000_000, 1_000_000_000)
        msg.effort = effort.tolist()
        pub.publish(msg)
    elapsed = time.perf_counter() - t0
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
    return {"sent": n, "rate_hz": n / elapsed}


def _inner(seconds: float, out: Path) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench_ros_"))
    env = dict(os.environ, MPLBACKEND="Agg")
    results: dict[str, object] = {}
    for name, cmd in (
        ("echo", [sys.executable, __file__, "--echo", str(tmp / "echo.json")]),
        ("monitor", [sys.executable, "-m", "reflexarm.cli", "ros", "monitor", "-p", "rearm_after:=0.3",
                     "-p", "joint_state_timeout:=0.5", "-p", f"qos_depth:={DEPTH}",
                     "-p", f"summary_file:={tmp / 'monitor.json'}", "--realtime-priority", str(REALTIME)]),
    ):  # fmt: skip
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            sent = _publish(seconds if name == "monitor" else min(seconds, 10.0), "echo" if name == "echo" else
                            "reflexarm_monitor")  # fmt: skip
        finally:
            proc.terminate()
            _, err = proc.communicate(timeout=60)
        node = json.loads((tmp / f"{name}.json").read_text())
        results[name] = {"publisher": sent, "node": node, "stderr": err[-2000:]}
    out.write_text(json.dumps(results))


def _report(results: dict, priority: int) -> dict[str, object]:
    echo, mon = results["echo"], results["monitor"]
    echo_ms = np.asarray(echo["node"]["latency_ns"]) * 1e-6
    summary = mon["node"]
    ticks, events = summary["latency"]["ticks"], summary["latency"]["events"]
    lost = mon["publisher"]["sent"] - summary["heard"]
    base = float(np.median(echo_ms))
    print(f"publisher: {mon['publisher']['sent']} JointState in {mon['publisher']['sent'] / 1000:.0f} s "
          f"(achieved {mon['publisher']['rate_hz']:.0f} Hz)")  # fmt: skip
    print(f"lost messages: {lost} (heard {summary['heard']}; stamp gaps {summary['lost_by_stamp']})")
    print(f"arrival -> tick published: median {ticks['median_ms']:.3f} ms, p99 {ticks['p99_ms']:.3f} ms "
          f"(ratio {ticks['median_ms'] / base:.2f}x / {ticks['p99_ms'] / np.percentile(echo_ms, 99):.2f}x the echo)")
    if events["count"]:
        print(f"arrival -> event published: {len(summary['events'])} events ({events['count']} publications: at "
              f"detection and with the estimate), median {events['median_ms']:.3f} ms, p99 {events['p99_ms']:.3f} ms, "
              f"max {events['max_ms']:.3f} ms")
    proc = summary["latency"]["processing"]
    print(f"the node's own tick (callback start -> published): median {proc['median_ms']:.3f} ms, "
          f"p99 {proc['p99_ms']:.3f} ms")
    print(f"baseline, bare rclpy echo: median {base:.3f} ms, p99 {np.percentile(echo_ms, 99):.3f} ms, "
          f"lost {echo['publisher']['sent'] - echo['node']['heard']} of {echo['publisher']['sent']}")  # fmt: skip
    print(f"node scheduler: {'SCHED_FIFO ' + str(priority) if priority else 'normal'}; "
          f"reliable, keep last {DEPTH} on both sides; goal: 0 lost; median <= 1 ms, p99 <= 5 ms (2 cores); "
          "load average now " + " ".join(f"{v:.1f}" for v in os.getloadavg()))
    return {"lost": lost, "sent": mon["publisher"]["sent"], "rate_hz": mon["publisher"]["rate_hz"],
            "tick_latency_ms": ticks, "event_latency_ms": events, "processing_ms": proc,
            "events": len(summary["events"]), "echo_median_ms": base, "echo_p99_ms": float(np.percentile(echo_ms, 99)),
            "load": os.getloadavg(), "realtime_priority": priority}  # fmt: skip


def main(seconds: float = SECONDS) -> dict[str, object]:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        print("skipped: the 'ros' extra (rclpy) is not installed")
        return {"skipped": "no rclpy"}
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        print(f"skipped: unshare -n is not permitted here ({probe.stderr.strip()}); DDS runs only on loopback")
        return {"skipped": "no unshare"}
    results: dict[str, object] = {}
    for priority in PRIORITIES:  # the normal scheduler, then SCHED_FIFO as a deployed control loop runs
        print(f"--- the node on {'SCHED_FIFO ' + str(priority) if priority else 'the normal scheduler'}")
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "results.json"
            inner = (f"ip link set lo up && exec env {INSIDE}=1 BENCH_ROS_REALTIME={priority} "
                     "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
                     f"{sys.executable} {__file__} --inner {seconds} {out}")  # fmt: skip
            res = subprocess.run(["unshare", "-n", "bash", "-c", inner], cwd=ROOT, capture_output=True, text=True)
            if res.returncode != 0 or not out.exists():
                print(f"failed: {res.stdout[-3000:]}{res.stderr[-3000:]}")
                results[f"fifo_{priority}"] = {"failed": res.returncode}
                continue
            results[f"fifo_{priority}"] = _report(json.loads(out.read_text()), priority)
    return results

if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--echo":
        _echo()
    elif len(sys.argv) > 1 and sys.argv[1] == "--inner":
        assert os.environ.get(INSIDE) == "1", "--inner runs only inside the bench's network namespace"
        _inner(float(sys.argv[2]), Path(sys.argv[3]))
    else:
        main(float(sys.argv[1]) if len(sys.argv) > 1 else SECONDS)
