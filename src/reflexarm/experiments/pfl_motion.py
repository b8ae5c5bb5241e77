"""A user's motion for the power-and-force-limiting runs: a sampled joint trajectory (a trajectory file, or the
excitation ``reflexarm excite --csv`` writes), time-scaled to sweep the speed.

:func:`read_motion_csv` reads either ``t, <one column per joint>`` [s, rad] or the excitation export's
``t, position_<joint>..., velocity_<joint>..., acceleration_<joint>...``. :class:`SampledMotion` interpolates
the samples (a cubic Hermite spline through the file's velocities when given, else a cubic spline through the
positions) and plays them time-scaled: ``motion.sample(t)`` at scale s is the motion at s t, with velocities
times s and accelerations times s^2, so the path is the same and every speed along it is s times the file's.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from reflexarm.errors import ConfigError
from reflexarm.robots import RobotModel
from reflexarm.signals import Reference

__all__ = ["SampledMotion", "SpeedLimitError", "read_motion_csv"]


class SpeedLimitError(ConfigError):
    """A speed a motion cannot reach within the joints' velocity limits.

    Attributes:
        speed: the speed asked for [m/s]; reachable_speed: the largest the motion reaches within the limits
            [m/s]; joint: the limiting joint (0-based).
    """

    def __init__(self, message: str, *, speed: float, reachable_speed: float, joint: int) -> None:
        super().__init__(message)
        self.speed, self.reachable_speed, self.joint = speed, reachable_speed, joint


class SampledMotion:
    """A joint motion through samples (t [s], q [rad], optionally dq [rad/s]), played from ``start`` [s] of the
    file's time at time scale ``scale`` [-] (> 1: faster): ``sample(t)`` is the file's motion at
    ``start + scale * t``. Before the first sample it holds the first, after the last the last.

    Raises:
        ConfigError: fewer than 2 samples, times not strictly increasing, shapes that do not match, non-finite
            values (named by sample), a non-positive scale.
    """

    def __init__(
        self,
        t: npt.ArrayLike,
        q: npt.ArrayLike,
        dq: npt.ArrayLike | None = None,
        *,
        scale: float = 1.0,
        start: float | None = None,
        name: str = "motion",
    ) -> None:
        ta = np.asarray(t, dtype=float).reshape(-1)
        qa = np.asarray(q, dtype=float)
        if qa.ndim != 2 or qa.shape[0] != ta.size or ta.size < 2:
            raise ConfigError(f"a motion needs >= 2 samples of t (N,) and q (N, n); got {ta.shape} and {qa.shape}")
        for label, a in (("t", ta), ("q", qa)) + ((("dq", np.asarray(dq, dtype=float)),) if dq is not None else ()):
            bad = np.flatnonzero(~np.all(np.isfinite(a.reshape(ta.size, -1)), axis=1))
            if bad.size:
                raise ConfigError(f"{name}: {label} is not finite at sample(s) {bad[:5].tolist()}")
        steps = np.flatnonzero(np.diff(ta) <= 0.0)
        if steps.size:
            i = int(steps[0])
            raise ConfigError(
                f"{name}: time must increase strictly; t = {ta[i]:g} s then {ta[i + 1]:g} s at sample {i + 1}"
            )
        if not (math.isfinite(scale) and scale > 0.0):
            raise ConfigError(f"time scale must be positive; got {scale!r}")
        self.t, self.q, self.name, self.scale = ta, qa, name, float(scale)
        self.start = float(ta[0] if start is None else start)
        if dq is None:
            self._spline: CubicSpline | CubicHermiteSpline = CubicSpline(ta, qa, axis=0)
        else:
            dqa = np.asarray(dq, dtype=float)
            if dqa.shape != qa.shape:
                raise ConfigError(f"{name}: dq must have the shape of q {qa.shape}; got {dqa.shape}")
            self._spline = CubicHermiteSpline(ta, qa, dqa, axis=0)
        self._d1 = self._spline.derivative(1)
        self._d2 = self._spline.derivative(2)

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    @property
    def duration(self) -> float:
        """From ``start`` to the last sample at this scale [s]."""
        return (float(self.t[-1]) - self.start) / self.scale

    def played(self, scale: float, start: float | None = None) -> SampledMotion:
        """The same samples played at time scale ``scale`` from file time ``start`` [s] (default the first)."""
        out = SampledMotion.__new__(SampledMotion)
        out.__dict__.update(self.__dict__)
        if not (math.isfinite(scale) and scale > 0.0):
            raise ConfigError(f"time scale must be positive; got {scale!r}")
        out.scale = float(scale)
        out.start = float(self.t[0] if start is None else start)
        return out

    def file_time(self, t: npt.ArrayLike) -> np.ndarray:
        """The file's time [s] at play time ``t`` [s]."""
        return np.asarray(self.start + self.scale * np.asarray(t, dtype=float))

    def at_file_time(self, tau: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, ddq) at file times ``tau`` at this scale: [rad], [rad/s], [rad/s^2] (held outside the file)."""
        x = np.clip(np.asarray(tau, dtype=float), self.t[0], self.t[-1])
        inside = ((np.asarray(tau) >= self.t[0]) & (np.asarray(tau) <= self.t[-1]))[..., None]
        s = self.scale
        return (
            np.asarray(self._spline(x)),
            np.where(inside, s * self._d1(x), 0.0),
            np.where(inside, s * s * self._d2(x), 0.0),
        )

    def sample(self, t: float) -> Reference:
        q, dq, ddq = self.at_file_time(float(self.file_time(t)))
        return Reference(q, dq, ddq)

    def dense(self, dt: float = 0.002) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(file times [s], q, dq at this scale) every ``dt`` [s] of file time over the whole file."""
        tau = np.arange(self.t[0], self.t[-1] + 0.5 * dt, dt)
        q, dq, _ = self.at_file_time(tau)
        return tau, q, dq

    def velocity_ratio(self, robot: RobotModel) -> tuple[float, int]:
        """(max over the file of |dq_j| / velocity limit_j at this scale [-], the joint j (0-based))."""
        _, _, dq = self.dense()
        vlim = np.asarray(robot.velocity_limit, dtype=float)
        ratio = np.max(np.abs(dq), axis=0) / np.where(np.isfinite(vlim) & (vlim > 0.0), vlim, np.inf)
        j = int(np.argmax(ratio))
        return float(ratio[j]), j


def _columns(cols: list[str], n: int, path: str) -> tuple[list[str], list[str] | None]:
    """(position columns, velocity columns or None) of a header, or a ConfigError naming what was found."""
    pos = [c for c in cols if c.startswith("position_")]
    vel = [c for c in cols if c.startswith("velocity_")]
    if cols[:1] == ["t"] and len(pos) == n:
        return pos, (vel if len(vel) == n else None)
    if cols[:1] == ["t"] and not pos and len(cols) == n + 1:
        return cols[1:], None
    raise ConfigError(
        f"--trajectory {path!r} needs columns t and {n} joint positions [rad] (or the excitation export's t, "
        f"position_<joint>..., velocity_<joint>...); found {cols}"
    )


def read_motion_csv(path: str | Path, robot: RobotModel) -> SampledMotion:
    """The motion in the CSV file ``path`` for ``robot`` (module docstring).

    Raises:
        ConfigError: a file that cannot be read, the wrong columns (the message lists those found), a cell that is
            not a number, times not strictly increasing, fewer than 2 samples.
    """
    p = str(path)
    try:
        with open(path) as fh:
            header = fh.readline().strip()
        data = np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2, invalid_raise=True)
    except (OSError, ValueError) as e:
        raise ConfigError(f"cannot read --trajectory {p!r}: {e}") from e
    cols = [c.strip() for c in header.split(",")]
    pos, vel = _columns(cols, robot.n, p)
    if data.ndim != 2 or data.shape[1] != len(cols):
        raise ConfigError(f"--trajectory {p!r}: rows must have {len(cols)} numbers like the header; got {data.shape}")
    bad = np.argwhere(~np.isfinite(data))
    if bad.size:
        r, c = (int(x) for x in bad[0])
        raise ConfigError(f"--trajectory {p!r}: column {cols[c]!r} is not a number in data row {r + 1}")
    t = data[:, 0]
    q = data[:, [cols.index(c) for c in pos]]
    dq = None if vel is None else data[:, [cols.index(c) for c in vel]]
    return SampledMotion(t, q, dq, name=Path(p).name)
