"""What both nodes share: declaring the parameter table, QoS profiles, running a node until it is done or stopped."""

from __future__ import annotations

import signal
from collections.abc import Callable
from typing import Any, Protocol

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

__all__ = ["declare_parameters", "reliable", "run_node"]


def reliable(depth: int) -> QoSProfile:
    """KEEP_LAST ``depth``, RELIABLE, VOLATILE (ROS 2's system defaults with a chosen depth)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


def declare_parameters(node: Node, table: tuple[tuple[str, Any, str], ...]) -> dict[str, Any]:
    """Declare every (name, default, description) of ``table`` on ``node``; their values by name."""
    out = {}
    for name, default, description in table:
        param = node.declare_parameter(name, default, ParameterDescriptor(description=description))
        out[name] = param.value
    return out


class ClosableNode(Protocol):
    done: bool

    def close(self) -> None: ...

    def destroy_node(self) -> None: ...


def run_node(make: Callable[[], Any], spin: Callable[[Any, SingleThreadedExecutor], None] | None = None) -> int:
    """Init rclpy (no signal handlers of its own: Ctrl-C and SIGTERM raise KeyboardInterrupt here, so that the node
    can still publish a last safe command and write its summary), build the node, spin it until ``node.done`` or a
    stop, then ``node.close()`` and shut down. ``spin(node, executor)`` replaces the plain spin loop."""
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)  # the command line is argparse's

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    node = None
    try:
        node = make()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if spin is not None:
            spin(node, executor)
        else:
            while rclpy.ok() and not node.done:
                executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        if node is not None:
            try:
                node.close()
            finally:
                node.destroy_node()
        rclpy.try_shutdown()
    return 0
