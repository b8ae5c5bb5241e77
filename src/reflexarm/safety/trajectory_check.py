"""A whole motion checked against a body region's transient limit: at every sample, the speed of each point
most likely to hit, beside the permissible speed at that posture in that direction (ISO/TS 15066 A.3 with the
arm's posture-dependent effective mass).

The contact direction of a point is its own velocity direction (a person standing in its way is hit
head-on, the relative speed being the point's whole speed). Samples above the limit are reported one by
one, never clipped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots import RobotModel
from reflexarm.safety.body_regions import BodyRegion, body_region
from reflexarm.safety.effective_mass import (
    ContactPoint,
    contact_points,
    effective_mass,
    permissible_speed_for_mass,
    point_jacobian,
    standard_robot_mass,
)

__all__ = ["SpeedCheck", "check_trajectory_speed"]

#: Below this speed [m/s] a point is at rest: no direction, no contact (its ratio is 0).
REST_SPEED = 1e-6


@dataclass(frozen=True)
class SpeedCheck:
    """The check of one motion against one region; arrays have one row per sample and one column per point.

    Attributes:
        region: the body region (its limits).
        points: the points checked (labels).
        t: sample times [s].
        speed: each point's speed [m/s].
        effective_mass: m_R(q, u) of each point along its velocity [kg].
        permissible_speed: v_max at that posture and direction [m/s].
        standard_mass: the standard's M/2 + m_L [kg]; ``standard_speed`` its v_max [m/s].
    """

    region: BodyRegion
    points: tuple[str, ...]
    t: np.ndarray
    speed: np.ndarray
    effective_mass: np.ndarray
    permissible_speed: np.ndarray
    standard_mass: float
    standard_speed: float
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def ratio(self) -> np.ndarray:
        """speed / permissible speed [-] (> 1: over the limit)."""
        return np.asarray(self.speed / self.permissible_speed)

    @property
    def exceeded(self) -> np.ndarray:
        """(N,) bool: some point over its permissible speed at that sample."""
        return np.asarray(np.any(self.ratio > 1.0, axis=1))

    def violations(self) -> list[dict[str, object]]:
        """One record per sample over the limit: time [s], the worst point, its speed and the permissible one
        [m/s], m_R [kg] and the ratio."""
        out: list[dict[str, object]] = []
        ratio = self.ratio
        for k in np.flatnonzero(self.exceeded):
            j = int(np.argmax(ratio[k]))
            out.append(
                {
                    "sample": int(k),
                    "t_s": float(self.t[k]),
                    "point": self.points[j],
                    "speed_m_s": float(self.speed[k, j]),
                    "permissible_speed_m_s": float(self.permissible_speed[k, j]),
                    "effective_mass_kg": float(self.effective_mass[k, j]),
                    "ratio": float(ratio[k, j]),
                }
            )
        return out

    def summary(self) -> dict[str, object]:
        """JSON-ready: the region, the worst sample, how many samples exceed."""
        ratio = self.ratio
        k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        return {
            "region": self.region.name,
            "samples": int(self.t.size),
            "samples_over_limit": int(self.exceeded.sum()),
            "worst_t_s": float(self.t[k]),
            "worst_point": self.points[j],
            "worst_speed_m_s": float(self.speed[k, j]),
            "worst_permissible_speed_m_s": float(self.permissible_speed[k, j]),
            "worst_ratio": float(ratio[k, j]),
            "min_permissible_speed_m_s": float(np.min(self.permissible_speed)),
            "standard_mass_kg": self.standard_mass,
            "standard_permissible_speed_m_s": self.standard_speed,
        }


def _samples(t: npt.ArrayLike, q: npt.ArrayLike, dq: npt.ArrayLike, n: int) -> tuple[np.ndarray, ...]:
    ta = np.asarray(t, dtype=float).reshape(-1)
    qa, dqa = np.asarray(q, dtype=float), np.asarray(dq, dtype=float)
    if qa.ndim != 2 or qa.shape != dqa.shape or qa.shape != (ta.size, n):
        raise ConfigError(
            f"t, q, dq must have shapes (N,), (N, {n}), (N, {n}); got {ta.shape}, {qa.shape}, {dqa.shape}"
        )
    for name, a in (("t", ta), ("q", qa), ("dq", dqa)):
        bad = np.flatnonzero(~np.all(np.isfinite(a.reshape(ta.size, -1)), axis=1))
        if bad.size:
            raise ConfigError(f"{name} is not finite at sample(s) {bad[:5].tolist()} (t = {ta[bad[:5]].tolist()} s)")
    return ta, qa, dqa


def check_trajectory_speed(
    robot: RobotModel,
    t: npt.ArrayLike,
    q: npt.ArrayLike,
    dq: npt.ArrayLike,
    region: str | BodyRegion,
    *,
    points: Sequence[ContactPoint | str] | None = None,
    payload: float = 0.0,
) -> SpeedCheck:
    """Check the motion (t [s], q [rad], dq [rad/s], one row per sample) against ``region``'s transient limit
    at the points ``points`` (default :func:`~reflexarm.safety.effective_mass.contact_points`).

    Raises:
        ConfigError: shapes that do not match the arm, non-finite samples (named), an unknown region.
        ModelError: an unknown frame among ``points``.
    """
    r = body_region(region)
    pts = contact_points(robot, points)
    ta, qa, dqa = _samples(t, q, dq, robot.n)
    speed = np.zeros((ta.size, len(pts)))
    mass = np.full((ta.size, len(pts)), np.inf)
    for k in range(ta.size):
        for j, p in enumerate(pts):
            J, _ = point_jacobian(robot, qa[k], p.link, p.point)
            v = J @ dqa[k]
            s = float(np.linalg.norm(v))
            speed[k, j] = s
            if s > REST_SPEED:
                mass[k, j] = effective_mass(robot, qa[k], p.link, p.point, v / s)
    vmax = np.array([[permissible_speed_for_mass(m, r) for m in row] for row in mass])
    m_std = standard_robot_mass(robot, payload)
    return SpeedCheck(
        region=r,
        points=tuple(p.label() for p in pts),
        t=ta,
        speed=speed,
        effective_mass=mass,
        permissible_speed=vmax,
        standard_mass=m_std,
        standard_speed=permissible_speed_for_mass(m_std, r),
        meta={"robot": robot.name, "payload_kg": payload},
    )
