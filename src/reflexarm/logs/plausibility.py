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

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

from reflexarm.errors import DataError, ImplausibleDataError

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

#: Largest magnitude a logged value may have, whatever the robot, per signal (SI units):
#: q 1e4 rad (1,600 turns: an unwrapped continuous joint of a long log stays below), dq 1e3 rad/s
#: (~10,000 rpm at the joint, beyond any arm's output), ddq 1e6 rad/s^2 (the finite difference of a
#: 1 kHz velocity jumping by 1e3 rad/s), tau and the wrench 1e6 Nm / N (ten times the largest industrial
#: arm's base torque).
ABSOLUTE_BOUNDS: Mapping[str, float] = {"q": 1e4, "dq": 1e3, "ddq": 1e6, "tau": 1e6, "tau_raw": 1e6, "wrench": 1e6}

#: A measured torque beyond this multiple of the joint's effort limit is implausible [-].
TORQUE_LIMIT_FACTOR = 10.0
#: A measured velocity beyond this multiple of the joint's velocity limit is implausible [-].
VELOCITY_LIMIT_FACTOR = 10.0
#: A position this far outside the joint's range is implausible [rad] (a quarter turn: the log is in
#: degrees, of another joint order, or of another robot).
POSITION_MARGIN = 0.5 * np.pi

#: How many offending cells an error lists.
_SHOWN = 5

_WRENCH = ("fx", "fy", "fz", "mx", "my", "mz")
_UNITS = {"q": "rad", "dq": "rad/s", "ddq": "rad/s^2", "tau": "Nm", "tau_raw": "Nm", "wrench": "N or Nm"}


class BadSample(NamedTuple):
    """One suspicious cell of a log.

    Attributes:
        source: the log's name; row: 0-based data row; t: its time [s]; column: schema name
        (``tau_3``, ``fx``); value: the value; reference: the bound it exceeds (plausibility checks) or
        the typical magnitude of its column (:func:`likely_bad_rows`).
    """

    source: str
    row: int
    t: float
    column: str
    value: float
    reference: float

    def __str__(self) -> str:
        return f"row {self.row} (t = {self.t:.6g} s) {self.column} = {self.value:.6g}"


def _column(name: str, j: int) -> str:
    return _WRENCH[j] if name == "wrench" else f"{name}_{j + 1}"


def _offenders(
    source: str, t: np.ndarray, name: str, values: np.ndarray, bad: np.ndarray, bound: np.ndarray
) -> list[BadSample]:
    """The first :data:`_SHOWN` True cells of ``bad`` (N, k) in row order."""
    cells = np.argwhere(bad)[:_SHOWN]
    return [
        BadSample(source, int(r), float(t[r]), _column(name, int(c)), float(values[r, c]), float(bound[c]))
        for r, c in cells
    ]


def _error(source: str, name: str, found: list[BadSample], n_rows: int, rule: str) -> ImplausibleDataError:
    listed = "; ".join(str(s) for s in found)
    return ImplausibleDataError(
        f"{source}: {n_rows:,} row(s) with implausible {name} [{_UNITS.get(name, '')}] ({rule}): {listed}"
        + (" ..." if n_rows > len(found) else ""),
        tuple(found),
    )


def check_absolute_bounds(source: str, t: np.ndarray, arrays: Mapping[str, np.ndarray | None]) -> None:
    """Raise :class:`ImplausibleDataError` if a cell of ``arrays`` (name -> (N, k)) exceeds its
    :data:`ABSOLUTE_BOUNDS` entry in magnitude (names without a bound are not checked)."""
    for name, values in arrays.items():
        bound = ABSOLUTE_BOUNDS.get(name)
        if values is None or bound is None:
            continue
        v = values if values.ndim == 2 else values[:, None]
        bad = np.abs(v) > bound
        if bad.any():
            found = _offenders(source, t, name, v, bad, np.full(v.shape[1], bound))
            raise _error(source, name, found, int(bad.any(axis=1).sum()), f"|{name}| > {bound:g} for any robot")


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
        from reflexarm.logs.units import check_units  # units imports BadSample from here

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
