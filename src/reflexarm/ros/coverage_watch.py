"""The live node's coverage check (issue 17 item 5): the thresholds file of ``tune-thresholds`` stores per joint
the positions and speed its logs covered; a motion outside them runs on levels that were never tuned on such
motion. The node warns once per joint (a WARN diagnostic and a log line, not a fault: the command is unchanged
and detection stays on), with the same margins as ``reflexarm detect`` (:func:`reflexarm.detect.check_coverage`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from reflexarm.detect.coverage import MARGIN_SHARE, MIN_MARGIN, MIN_SPEED, JointCoverage

__all__ = ["CoverageWatch"]


class CoverageWatch:
    """Per tick: which joints are outside the tuned coverage for the first time."""

    def __init__(self, coverage: Sequence[JointCoverage], n: int) -> None:
        self.coverage = list(coverage)
        self.lo = np.full(n, -np.inf)
        self.hi = np.full(n, np.inf)
        self.speed = np.full(n, np.inf)
        for c in self.coverage:
            margin = max(MARGIN_SHARE * (c.q_max - c.q_min), MIN_MARGIN)
            self.lo[c.joint], self.hi[c.joint] = c.q_min - margin, c.q_max + margin
            self.speed[c.joint] = c.speed * (1.0 + MARGIN_SHARE) + (0.0 if c.moved else MIN_SPEED)
        self._by_joint = {c.joint: c for c in self.coverage}
        self.warned: dict[int, str] = {}

    @classmethod
    def from_threshold(cls, threshold: str, n: int) -> CoverageWatch | None:
        """The watch of a thresholds.json with a stored coverage; None for a level given as numbers or a file
        without one (the caller says so)."""
        path = Path(str(threshold).strip())
        if path.suffix.lower() != ".json" or not path.is_file():
            return None
        doc = json.loads(path.read_text())
        stored = doc.get("coverage") if isinstance(doc, dict) else None
        if not isinstance(stored, list):
            return None
        return cls([JointCoverage.from_dict(c) for c in stored], n)

    def check(self, t: float, q: np.ndarray, dq: np.ndarray) -> list[str]:
        """The warning lines of the joints that leave the coverage at this sample for the first time."""
        outside = (q < self.lo) | (q > self.hi) | (np.abs(dq) > self.speed)
        if not outside.any():
            return []
        lines = []
        for j in (int(i) for i in np.flatnonzero(outside)):
            if j in self.warned or j not in self._by_joint:
                continue
            c = self._by_joint[j]
            what = "" if c.moved else " (a joint that did not move in the tuning logs)"
            line = (
                f"joint {j + 1} ({c.name}){what} left the tuned coverage at t = {t:.3f} s: q = {q[j]:.4g} rad "
                f"(covered [{c.q_min:.4g}, {c.q_max:.4g}]), |dq| = {abs(dq[j]):.4g} rad/s (covered <= "
                f"{c.speed:.4g}): its level was not tuned on such motion"
            )
            self.warned[j] = line
            lines.append(line)
        return lines
