"""What :func:`reflexarm.detect.run.detect_collisions` found in one log (a module of its own, below the run and
its figure, which both read it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from reflexarm.detect.coverage import Outside
from reflexarm.detect.events import DetectedEvent
from reflexarm.detect.glitches import Glitch
from reflexarm.tuning.replay import ObserverSettings

__all__ = ["LogDetection"]


@dataclass
class LogDetection:
    """What :func:`detect_collisions` found in one log."""

    source: str
    t: np.ndarray
    residual: np.ndarray
    zeta: np.ndarray
    dt: float
    settings: ObserverSettings
    events: list[DetectedEvent]
    glitches: list[Glitch]
    outside: list[Outside]
    fault_ticks: int
    joint_names: list[str]
    notes: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        """Span of the log [s] (N samples of dt)."""
        return float(self.t.size * self.dt)

    @property
    def rate_hz(self) -> float:
        """The log's sample rate [Hz] (1 / its median period)."""
        return 1.0 / self.dt

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary of the log (events listed separately)."""
        return {
            "log": self.source,
            "samples": int(self.t.size),
            "duration_s": self.duration,
            "period_s": self.dt,
            "delay_resolution_s": self.dt,
            "events": len(self.events),
            "glitches": [g.as_dict() for g in self.glitches],
            "outside_coverage": [o.line() for o in self.outside],
            "fault_ticks": self.fault_ticks,
            "notes": list(self.notes),
        }
