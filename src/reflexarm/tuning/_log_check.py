"""Levels against the logs they came from: how often the logs cross a level, and the lowest level they
cross no more often than allowed (used by :func:`reflexarm.tuning.tune_thresholds`)."""

from __future__ import annotations

import math

import numpy as np

from reflexarm.tuning.tail import TailFit, cluster_maxima

__all__ = ["count_crossings", "lowest_level_crossed_at_most"]


def count_crossings(parts: list[np.ndarray], level: float, dt: float, fit: TailFit) -> tuple[int, float]:
    """(alarms at ``level`` counted in the logs, alarms the fitted rate at ``level`` predicts over their span)."""
    gap = int(math.ceil(fit.gap_s / dt - 1e-9))
    counted = sum(cluster_maxima(p, level, gap).size for p in parts)
    return int(counted), float(fit.rate(level) * fit.duration_h)


def lowest_level_crossed_at_most(parts: list[np.ndarray], level: float, dt: float, fit: TailFit, allowed: int) -> float:
    """The lowest level from ``level`` up (0.5 % steps of the way to the logs' maximum) that the logs cross
    at most ``allowed`` times."""
    for z in np.linspace(level, fit.x_max, 201):
        if count_crossings(parts, float(z), dt, fit)[0] <= allowed:
            return float(z)
    return fit.x_max
