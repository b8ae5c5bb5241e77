"""When a logged value is garbage: plausibility bounds on logs, and the rows behind a failed fit.

Two layers of bounds, each a documented constant:

* **absolute** (:data:`ABSOLUTE_BOUNDS`), applied to every :class:`~reflexarm.ident.RobotLog` when it is
  built (loading, preprocessing, selecting): values no robot arm produces, whatever the robot. They
  catch overflowing sensors, uninitialised memory (1e300), wrong units by orders of magnitude and
  corrupt files. A cell beyond its bound raises :class:`~reflexarm.errors.ImplausibleDataError` naming
  the column, the row, the value and the bound.
* **relative to the robot** (:func:`check_log_against_robot`, with the unit checks of
  :mod:`reflexarm.logs.units`, applied by
  :func:`~reflexarm.ident.identify_dynamics` and, as :func:`check_samples_against_robot`, by
  :func:`~reflexarm.ident.identify_joint_friction`): a measured torque beyond :data:`TORQUE_LIMIT_FACTOR` times
  the joint's effort limit, a velocity beyond :data:`VELOCITY_LIMIT_FACTOR` times its velocity limit,
  a position more than :data:`POSITION_MARGIN` outside its range. A real log stays within its robot's
  limits (a torque sensor saturates near them); a value 10x beyond is a glitch, a unit error (degrees)
  or a log of another robot, and would drag the least-squares estimate wherever it likes.

When a fit nevertheless comes out non-finite (e.g. variances given so small that the weighted problem
overflows), :func:`likely_bad_rows` names the samples that stand out most from their column.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from reflexarm.errors import DataError
from reflexarm.logs.bounds import _SHOWN, ABSOLUTE_BOUNDS, BadSample, _column, _error, _offenders, check_absolute_bounds

if TYPE_CHECKING:
    from reflexarm.logs.robot_log import RobotLog
    from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "ABSOLUTE_BOUNDS",
    "POSITION_MARGIN",
    "TORQUE_LIMIT_FACTOR",
    "VELOCITY_LIMIT_FACTOR",
    "BadSample",
    "check_absolute_bounds",
    "check_log_against_robot",
    "check_samples_against_robot",
    "likely_bad_rows",
]

#: A measured torque beyond this multiple of the joint's effort limit is implausible [-].
TORQUE_LIMIT_FACTOR = 10.0
#: A measured velocity beyond this multiple of the joint's velocity limit is implausible [-].
VELOCITY_LIMIT_FACTOR = 10.0
#: A position this far outside the joint's range is implausible [rad] (a quarter turn: the log is in
#: degrees, of another joint order, or of another robot).
POSITION_MARGIN = 0.5 * np.pi

def check_log_against_robot(log: RobotLog, robot: RobotModel) -> None:
    """Raise :class:`ImplausibleDataError` if ``log`` leaves ``robot``'s limits by far (see the module
    docstring: torque beyond :data:`TORQUE_LIMIT_FACTOR` x effort limit, velocity beyond
    :data:`VELOCITY_LIMIT_FACTOR` x velocity limit, position :data:`POSITION_MARGIN` outside the range).
    Limits that are not finite and positive (a file without them, continuous joints) are not checked."""
    check_samples_against_robot(log.source, log.t, log.q, log.dq, log.measured_torque, robot, ddq=log.ddq)


def check_samples_against_robot(
    source: str,
    t: npt.ArrayLike,
    q: npt.ArrayLike,
    dq: npt.ArrayLike,
    tau: npt.ArrayLike,
    robot: RobotModel,
    *,
    ddq: npt.ArrayLike | None = None,
    units: bool = True,
) -> None:
    """:func:`check_log_against_robot` for plain (N,) time and (N, n) position, velocity and measured
    torque arrays (e.g. the constant-velocity runs of :func:`~reflexarm.ident.identify_joint_friction`);
    ``source`` names them in the message. After the limits, the unit checks of
    :mod:`reflexarm.logs.units` (``units``): positions against velocities, continuous joints in degrees,
    the torque's scale against the robot's model (``ddq``, if given, is used there)."""

    def usable(limit: np.ndarray) -> np.ndarray:
        return np.isfinite(limit) & (limit > 0) & (limit < 1e30)

    tt = np.asarray(t, dtype=float).reshape(-1)
    Q, DQ, torque = (np.asarray(a, dtype=float) for a in (q, dq, tau))
    for name, a in (("q", Q), ("dq", DQ), ("tau", torque)):
        if a.shape != (tt.size, robot.n):
            raise DataError(
                f"{source}: {name} must have shape ({tt.size}, {robot.n}) for {robot.name!r}; got {a.shape}"
            )
    effort = robot.effort_limit
    ok = usable(effort)
    bound = np.where(ok, TORQUE_LIMIT_FACTOR * effort, np.inf)
    bad = np.abs(torque) > bound
    if bad.any():
        found = _offenders(source, tt, "tau", torque, bad, bound)
        rule = f"beyond {TORQUE_LIMIT_FACTOR:g} x the effort limits {effort.tolist()} Nm of {robot.name!r}"
        raise _error(source, "tau", found, int(bad.any(axis=1).sum()), rule)
    vel = robot.velocity_limit
    bound = np.where(usable(vel), VELOCITY_LIMIT_FACTOR * vel, np.inf)
    bad = np.abs(DQ) > bound
    if bad.any():
        found = _offenders(source, tt, "dq", DQ, bad, bound)
        rule = f"beyond {VELOCITY_LIMIT_FACTOR:g} x the velocity limits {vel.tolist()} rad/s of {robot.name!r}"
        raise _error(source, "dq", found, int(bad.any(axis=1).sum()), rule)
    lo, hi = robot.lower_limit, robot.upper_limit
    ranged = np.isfinite(lo) & np.isfinite(hi) & (hi > lo) & (hi - lo < 1e30)
    lo_b = np.where(ranged, lo - POSITION_MARGIN, -np.inf)
    hi_b = np.where(ranged, hi + POSITION_MARGIN, np.inf)
    bad = (Q < lo_b) | (Q > hi_b)
    if bad.any():
        side = np.where(np.abs(Q - lo_b) < np.abs(Q - hi_b), lo_b, hi_b)
        cells = np.argwhere(bad)[:_SHOWN]
        found = [
            BadSample(source, int(r), float(tt[r]), f"q_{c + 1}", float(Q[r, c]), float(side[r, c])) for r, c in cells
        ]
        rule = (
            f"more than {POSITION_MARGIN:.3g} rad outside the joint ranges of {robot.name!r}: lower {lo.tolist()}, "
            f"upper {hi.tolist()} rad; degrees instead of radians?"
        )
        raise _error(source, "q", found, int(bad.any(axis=1).sum()), rule)
    if units:
        from reflexarm.logs.units import check_units

        check_units(source, tt, Q, DQ, torque, robot, None if ddq is None else np.asarray(ddq, dtype=float))


#: A cell stands out when its magnitude is at least this many times its column's 99th percentile of
#: magnitudes (a scale one absurd cell cannot inflate, unlike the maximum or the standard deviation, and
#: not fooled by the two-signed, nearly constant torque of a friction-dominated joint, unlike the median
#: absolute deviation).
OUTLIER_SCORE = 100.0


def likely_bad_rows(logs: Sequence[RobotLog], k: int = _SHOWN, min_score: float = OUTLIER_SCORE) -> list[BadSample]:
    """Up to ``k`` cells over ``logs`` that stand out most from their column, by at least ``min_score``.

    Score of a cell: its magnitude over its column's 99th percentile of magnitudes (see
    :data:`OUTLIER_SCORE`). Each returned sample's ``reference`` is that percentile.
    """
    scored: list[tuple[float, BadSample]] = []
    for lg in logs:
        for name in ("tau", "q", "dq", "ddq", "wrench"):
            values = getattr(lg, name)
            if values is None:
                continue
            mag = np.abs(values)
            typical = np.percentile(np.where(np.isfinite(mag), mag, 0.0), 99.0, axis=0)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                z = mag / np.maximum(typical, 1e-12)
            z = np.where(np.isnan(z), np.inf, z)
            flat = np.argsort(z, axis=None)[-k:]
            for r, c in zip(*np.unravel_index(flat, z.shape), strict=True):
                sample = BadSample(
                    lg.source, int(r), float(lg.t[r]), _column(name, int(c)), float(values[r, c]), float(typical[c])
                )
                scored.append((float(z[r, c]), sample))
    scored.sort(key=lambda s: -s[0])
    return [s for score, s in scored[:k] if score >= min_score]
