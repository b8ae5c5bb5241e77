"""Following the controller's collision event on the live stream: publish it at detection, again when the
isolation's estimate is in (with the contact wrench and arrow), estimate the onset, and say when a monitor may
re-arm."""

from __future__ import annotations

from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray

from reflexarm.control import Controller
from reflexarm.ros import outputs

__all__ = ["ONSET_SHARE", "EventTracker"]

#: A residual below this share of zeta on every joint counts as quiet: the event's ``delay_s`` is the time since
#: the last quiet tick (an estimate of the time from the contact's onset to detection).
ONSET_SHARE = 0.25
#: An isolation that gave no estimate this long after detection [s] is not waited for.
ESTIMATE_WAIT = 1.0


class EventTracker:
    """One per node. ``publishers``: ``events`` (DiagnosticArray), ``wrench`` (WrenchStamped), ``marker`` (Marker);
    ``node`` and ``hardware_id`` name the statuses, ``frame`` is the base frame of the wrench and the arrow."""

    def __init__(self, controller: Controller, publishers: dict[str, Any], *, node: str, hardware_id: str,
                 frame: str) -> None:  # fmt: skip
        self.controller = controller
        self.pub = publishers
        self.node, self.hardware_id, self.frame = node, hardware_id, frame
        zeta = controller.detector.threshold if controller.detector is not None else np.inf
        self._inv_zeta = 1.0 / np.broadcast_to(np.asarray(zeta, dtype=float), (controller.n,))
        self._buf = np.zeros(controller.n)
        self.events: list[dict[str, Any]] = []
        self.open = self._final = False
        self._t_quiet = self.t_below = 0.0

    def follow(self, t: float, residual: np.ndarray, collision: bool, stamp: Any, t0_ns: int) -> bool:
        """The tick at ``t`` [s] (input ``stamp``): True when it published the event."""
        buf = self._buf
        np.abs(residual, out=buf)
        buf *= self._inv_zeta
        ratio = float(buf.max())
        if ratio < ONSET_SHARE:
            self._t_quiet = t
        if ratio >= 1.0:
            self.t_below = t
        if not collision or (self.open and self._final):
            return False
        return self._publish(t, stamp, t0_ns)

    def _publish(self, t: float, stamp: Any, t0_ns: int) -> bool:
        event = self.controller.event
        if event is None:
            return False
        final = event.estimate is not None or self.controller.contact_geometry is None
        final = final or t - event.t_detect > ESTIMATE_WAIT
        if self.open and not final:
            return False
        if not self.open:
            self.open = True
            self.events.append({"number": len(self.events) + 1, "delay_s": event.t_detect - self._t_quiet})
        record = self.events[-1]
        record.update(event.to_dict())
        self._final = final
        status = outputs.event_status(record["number"], event, node=self.node, hardware_id=self.hardware_id,
                                      t0_ns=t0_ns, onset_delay=record["delay_s"])  # fmt: skip
        array = DiagnosticArray()
        array.header.stamp = stamp
        array.status = [status]
        self.pub["events"].publish(array)
        wrench = outputs.contact_wrench(stamp, self.frame, event)
        if wrench is not None:
            self.pub["wrench"].publish(wrench)
            self.pub["marker"].publish(outputs.contact_marker(stamp, self.frame, "contact", event))
        return True

    def close(self, stamp: Any) -> None:
        """The event is over (re-armed, reset): its arrow is deleted."""
        if self.open:
            self.pub["marker"].publish(outputs.contact_marker(stamp, self.frame, "contact", None))
        self.open = self._final = False
