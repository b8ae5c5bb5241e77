"""Coverage before trust: how much of each joint's range and speed the tuning logs covered, and whether a log to
check stays inside it (issue 17 item 5).

Levels tuned on free motion hold for the motions the logs contained: a joint that never moved gives a level of
its noise alone (0.03 Nm on a Kinova wrist, a false alarm 11 ms into a motion that moved it). The coverage is
stored in the thresholds file; ``reflexarm detect`` warns when a log leaves it.

Per joint: the position span [q_min, q_max] and the largest |dq| of the logs, as shares of the joint's range
(its limits; 2 pi for a joint without finite limits) and of its velocity limit. A joint *did not move* when its
span is below :data:`MIN_SPAN` or its speed below :data:`MIN_SPEED`. A sample is *outside* when its position
leaves the span by more than :data:`MARGIN_SHARE` of the span (at least :data:`MIN_MARGIN`), or its speed exceeds
the covered speed by that share.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError

__all__ = ["MARGIN_SHARE", "MIN_SPAN", "MIN_SPEED", "JointCoverage", "Outside", "check_coverage", "measure_coverage"]

#: A joint moved when its position span reaches this [rad or m] ...
MIN_SPAN = 0.05
#: ... and its largest |dq| this [rad/s or m/s].
MIN_SPEED = 0.05
#: Tolerance beyond the covered span and speed, as a share of them.
MARGIN_SHARE = 0.1
#: Smallest position tolerance [rad or m] (the noise of a joint that barely moved).
MIN_MARGIN = 0.02


@dataclass(frozen=True)
class JointCoverage:
    """What the logs covered of one joint (0-based ``joint``)."""

    joint: int
    name: str
    q_min: float
    q_max: float
    speed: float
    range_share: float
    speed_share: float | None

    @property
    def moved(self) -> bool:
        """True when the joint moved enough for its level to describe motion (module docstring)."""
        return self.q_max - self.q_min >= MIN_SPAN and self.speed >= MIN_SPEED

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (joint 1-based)."""
        return {
            "joint": self.joint + 1,
            "name": self.name,
            "q_min": self.q_min,
            "q_max": self.q_max,
            "speed_max": self.speed,
            "range_share": self.range_share,
            "speed_share": self.speed_share,
            "moved": self.moved,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> JointCoverage:
        """Back from :meth:`as_dict`."""
        share = d.get("speed_share")
        return cls(int(d["joint"]) - 1, str(d["name"]), float(d["q_min"]), float(d["q_max"]), float(d["speed_max"]),
                   float(d["range_share"]), None if share is None else float(share))  # fmt: skip

    def line(self) -> str:
        """One line for a report."""
        speed = "" if self.speed_share is None else f" ({100 * self.speed_share:.0f} % of its limit)"
        mark = "" if self.moved else "  NOT MOVED: its level describes noise only, not motion"
        return (f"  joint {self.joint + 1} ({self.name}): q in [{self.q_min:.3f}, {self.q_max:.3f}] "
                f"({100 * self.range_share:.0f} % of its range), |dq| <= {self.speed:.3f}{speed}{mark}")  # fmt: skip


def measure_coverage(q_parts: Sequence[np.ndarray], dq_parts: Sequence[np.ndarray], robot: Any) -> list[JointCoverage]:
    """The coverage per joint of logs given as their (N, n) positions and velocities, for ``robot`` (names and
    limits)."""
    if not q_parts:
        raise ConfigError("no log to measure the coverage of")
    q_min = np.min([np.min(q, axis=0) for q in q_parts], axis=0)
    q_max = np.max([np.max(q, axis=0) for q in q_parts], axis=0)
    speed = np.max([np.max(np.abs(dq), axis=0) for dq in dq_parts], axis=0)
    lower, upper = np.asarray(robot.lower_limit, float), np.asarray(robot.upper_limit, float)
    v_lim = np.asarray(robot.velocity_limit, float)
    out = []
    for j in range(robot.n):
        width = upper[j] - lower[j] if math.isfinite(upper[j] - lower[j]) and upper[j] > lower[j] else 2 * math.pi
        v_share = float(speed[j] / v_lim[j]) if math.isfinite(v_lim[j]) and v_lim[j] > 0 else None
        share = min(1.0, float((q_max[j] - q_min[j]) / width))
        out.append(JointCoverage(j, robot.joint_names[j], float(q_min[j]), float(q_max[j]), float(speed[j]), share,
                                 v_share))  # fmt: skip
    return out


@dataclass(frozen=True)
class Outside:
    """Where a log leaves the coverage of one joint: the share of its samples outside, the first time [s] and
    the farthest it went (position beyond the span [rad or m], speed above the covered one [rad/s or m/s])."""

    joint: int
    name: str
    share: float
    t_first: float
    beyond_position: float
    beyond_speed: float
    moved_in_tuning: bool

    def line(self) -> str:
        """One warning line."""
        what = "" if self.moved_in_tuning else " (a joint that did not move in the tuning logs)"
        return (f"joint {self.joint + 1} ({self.name}){what} is outside the tuned coverage in "
                f"{100 * self.share:.1f} % of the samples, first at t = {self.t_first:.3f} s (up to "
                f"{self.beyond_position:.3g} beyond the covered positions, {self.beyond_speed:.3g} above the covered "
                "speed): its level was not tuned on such motion")  # fmt: skip


def check_coverage(t: np.ndarray, q: np.ndarray, dq: np.ndarray, coverage: Sequence[JointCoverage]) -> list[Outside]:
    """The joints along which the log (t, q, dq) leaves ``coverage`` (module docstring), one entry each."""
    out = []
    for c in coverage:
        j = c.joint
        margin = max(MARGIN_SHARE * (c.q_max - c.q_min), MIN_MARGIN)
        below, above = c.q_min - margin - q[:, j], q[:, j] - c.q_max - margin
        fast = np.abs(dq[:, j]) - c.speed * (1.0 + MARGIN_SHARE) - (0.0 if c.moved else MIN_SPEED)
        bad = (below > 0) | (above > 0) | (fast > 0)
        if not np.any(bad):
            continue
        beyond = float(max(np.max(below), np.max(above), 0.0))
        out.append(Outside(j, c.name, float(np.mean(bad)), float(t[np.argmax(bad)]), beyond,
                           float(max(np.max(fast), 0.0)), c.moved))  # fmt: skip
    return out
