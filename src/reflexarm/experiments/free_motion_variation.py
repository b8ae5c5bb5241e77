"""Seeded variations of a cyclic free motion: another log of the same motion (tuning and held-out logs of one arm
differ in motion as well as in noise; :func:`~reflexarm.experiments.collision.free_motion_trajectory`)."""

from __future__ import annotations

import numpy as np

from reflexarm.robots import RobotModel
from reflexarm.sim import JointTrajectory

__all__ = ["FREE_MOTION_JITTER_RAD", "varied_cycles"]

#: Largest waypoint offset of a seeded free motion [rad].
FREE_MOTION_JITTER_RAD = 0.15


def varied_cycles(
    start: np.ndarray, cycle: np.ndarray, seg: float, duration: float, seed: int, robot: RobotModel | None
) -> JointTrajectory:
    """The cycle ``start -> cycle -> start`` repeated for ``duration``, varied by ``seed`` (see
    :func:`~reflexarm.experiments.collision.free_motion_trajectory`)."""
    rng = np.random.default_rng(seed)
    if robot is None:
        lo, hi = np.full(start.size, -np.inf), np.full(start.size, np.inf)
    else:
        lo, hi = robot.lower_limit, robot.upper_limit
    amp = np.minimum(FREE_MOTION_JITTER_RAD, 0.05 * np.where(np.isfinite(hi - lo), hi - lo, np.inf))
    way, times, total = [start], [], 0.0
    while total < duration:
        for q in (*cycle[rng.permutation(len(cycle))], start):
            moved = start if q is start else np.clip(q + rng.uniform(-amp, amp), lo, hi)
            way.append(moved)
            times.append(seg * rng.uniform(0.85, 1.2))
            total += times[-1]
    return JointTrajectory(np.array(way), np.array(times))
