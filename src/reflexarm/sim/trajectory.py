"""JointTrajectory: minimum-jerk (quintic) joint-space motion through waypoints."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.signals import Reference
from reflexarm.sim._kernels_lazy import kernels as _kernels

__all__ = ["JointTrajectory"]


class JointTrajectory:
    """Rest-to-rest quintic segments through joint-space waypoints, with optional holds.

    Each segment from waypoint ``i`` to ``i + 1`` follows the minimum-jerk profile
    ``q = q_i + (q_{i+1} - q_i) s(tau)``, ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``, ``tau = (t - t_i) / T_i``:
    velocity and acceleration are zero at every waypoint, so segments join smoothly. Before ``t0`` the
    trajectory holds the first waypoint, after the end the last one.

    Args:
        waypoints: (k, n) joint positions [rad], k >= 2.
        durations: (k - 1,) positive segment durations [s].
        t0: start time [s].
        holds: optional (k,) non-negative dwell times [s] spent at each waypoint before leaving it (the
            last one extends the trajectory's end).

    Raises:
        ConfigError: bad shapes, non-finite values, non-positive durations or negative holds.
    """

    def __init__(
        self,
        waypoints: npt.ArrayLike,
        durations: npt.ArrayLike,
        t0: float = 0.0,
        *,
        holds: npt.ArrayLike | None = None,
    ) -> None:
        try:
            W = np.array(waypoints, dtype=float)
            T = np.array(durations, dtype=float).reshape(-1)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"waypoints and durations must be numeric arrays: {e}") from e
        if W.ndim != 2 or W.shape[0] < 2 or W.shape[1] < 1:
            raise ConfigError(f"waypoints must have shape (k, n) with k >= 2 waypoints; got shape {W.shape}")
        k, n = W.shape
        if T.shape != (k - 1,):
            raise ConfigError(f"durations must have shape ({k - 1},) (one per segment of {k} waypoints); got {T.shape}")
        if not np.all(np.isfinite(W)):
            raise ConfigError("waypoints must be finite")
        if not np.all(np.isfinite(T)) or np.any(T <= 0.0):
            raise ConfigError(f"durations must be positive and finite [s]; got {T.tolist()}")
        if not math.isfinite(float(t0)):
            raise ConfigError(f"t0 must be finite; got {t0!r}")
        if holds is None:
            H = np.zeros(k)
        else:
            H = np.array(holds, dtype=float).reshape(-1)
            if H.shape != (k,) or not np.all(np.isfinite(H)) or np.any(H < 0.0):
                raise ConfigError(f"holds must be {k} non-negative finite times [s]; got {H.tolist()}")
        self.waypoints = W
        self.durations = T
        self.holds = H
        self.t0 = float(t0)
        self.n = n
        # segments: (start time, duration, q_from, delta); holds are segments with delta = 0
        starts: list[float] = []
        lengths: list[float] = []
        origins: list[np.ndarray] = []
        deltas: list[np.ndarray] = []
        t = self.t0
        for i in range(k):
            if H[i] > 0.0:
                starts.append(t)
                lengths.append(float(H[i]))
                origins.append(W[i])
                deltas.append(np.zeros(n))
                t += float(H[i])
            if i < k - 1:
                starts.append(t)
                lengths.append(float(T[i]))
                origins.append(W[i])
                deltas.append(W[i + 1] - W[i])
                t += float(T[i])
        self._starts = starts
        self._lengths = lengths
        self._origins = np.array(origins)
        self._deltas = np.array(deltas)
        self._t_end = t
        self._starts_arr = np.array(starts)
        self._lengths_arr = np.array(lengths)

    @classmethod
    def hold(cls, q: npt.ArrayLike, duration: float, t0: float = 0.0) -> JointTrajectory:
        """Hold ``q`` for ``duration`` seconds (and forever after)."""
        qq = np.asarray(q, dtype=float).reshape(-1)
        return cls(np.vstack([qq, qq]), [duration], t0)

    @property
    def duration(self) -> float:
        """Total time from ``t0`` to the end [s]."""
        return self._t_end - self.t0

    @property
    def t_end(self) -> float:
        """Absolute end time [s]."""
        return self._t_end

    def sample(self, t: float) -> Reference:
        """q_d, dq_d, ddq_d at time ``t`` [s] (fresh arrays)."""
        out = _kernels.quintic_sample(
            self._starts_arr, self._lengths_arr, self._origins, self._deltas, self._t_end, float(t)
        )
        return Reference(out[0], out[1], out[2])

    def sample_many(self, times: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, dq_d, ddq_d), each (len(times), n), for plotting and analysis."""
        ts = np.asarray(times, dtype=float).reshape(-1)
        q = np.empty((ts.size, self.n))
        dq = np.empty_like(q)
        ddq = np.empty_like(q)
        for k, t in enumerate(ts):
            q[k], dq[k], ddq[k] = self.sample(float(t))
        return q, dq, ddq

    def describe(self) -> dict[str, object]:
        """JSON-serialisable description (for ``Trace.meta``)."""
        return {
            "type": "JointTrajectory",
            "waypoints": self.waypoints.tolist(),
            "durations": self.durations.tolist(),
            "holds": self.holds.tolist(),
            "t0": self.t0,
        }

    def __repr__(self) -> str:
        return (
            f"JointTrajectory({self.waypoints.shape[0]} waypoints, n={self.n}, {self.duration:g} s from t0={self.t0:g})"
        )
