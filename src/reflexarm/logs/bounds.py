"""The bounds no robot's log exceeds (:data:`ABSOLUTE_BOUNDS`, checked on every
:class:`~reflexarm.logs.robot_log.RobotLog` when it is built) and the suspicious cell of a log
(:class:`BadSample`) that every plausibility error names: the lowest layer of the log checks, below the log
itself and the checks against a robot (:mod:`reflexarm.logs.plausibility`, :mod:`reflexarm.logs.units`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from reflexarm.errors import ImplausibleDataError

__all__ = ["ABSOLUTE_BOUNDS", "BadSample", "check_absolute_bounds"]

#: Largest magnitude a logged value may have, whatever the robot, per signal (SI units):
#: q 1e4 rad (1,600 turns: an unwrapped continuous joint of a long log stays below), dq 1e3 rad/s
#: (~10,000 rpm at the joint, beyond any arm's output), ddq 1e6 rad/s^2 (the finite difference of a
#: 1 kHz velocity jumping by 1e3 rad/s), tau and the wrench 1e6 Nm / N (ten times the largest industrial
#: arm's base torque).
ABSOLUTE_BOUNDS: Mapping[str, float] = {"q": 1e4, "dq": 1e3, "ddq": 1e6, "tau": 1e6, "tau_raw": 1e6, "wrench": 1e6}

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
