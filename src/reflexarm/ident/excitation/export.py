"""The excitation as a trajectory a robot can play: sampled positions, velocities and accelerations (CSV).

:func:`sample_excitation` evaluates a :class:`~reflexarm.ident.FourierTrajectory` at a chosen rate and
checks every sample against the robot's position limits, its velocity limits and an acceleration bound
(robot files carry none; the excitation's own bound by default). :func:`write_excitation_csv` writes it:

    t, position_<joint>, ..., velocity_<joint>, ..., acceleration_<joint>, ...

in s, rad (m for prismatic joints), rad/s, rad/s^2, one row per sample from t = 0 to the end of the last
period inclusive (the trajectory starts and ends at rest in the same pose). The column names are those of
a ROS ``sensor_msgs/JointState`` export, so the file reads back with :func:`reflexarm.ident.load_log`'s
column mapping.

The samples are also checked against the model's joint torques (inverse dynamics plus friction along the
samples, within the robot file's effort limits), the workspace (no point of the arm's collision surface
below the floor) and self-collision (capsules fitted to the collision geometry), see
:mod:`reflexarm.ident.excitation.limits`: the design's own bounds when given (``limits=design.limits``),
else the robot file's effort limits themselves and the default floor.

A sample beyond a limit is refused (:class:`ExcitationLimitError`, naming the joint 1-based, the quantity,
the value, the limit and by how much it is exceeded); a position or velocity sample within
``1 - WARN_FRACTION`` of a robot limit warns (:class:`ExcitationMarginWarning`). Sampling below
:data:`MIN_SAMPLES_PER_PERIOD` samples per period of the highest harmonic is refused: a controller
interpolating between such samples would not follow the designed motion.
"""

from __future__ import annotations

import csv
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.ident.excitation.design import DEFAULT_MAX_ACCELERATION, excitation_limits
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.ident.excitation.limits import ExcitationLimits, LimitEvaluator
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "MIN_SAMPLES_PER_PERIOD",
    "WARN_FRACTION",
    "ExcitationLimitError",
    "ExcitationMarginWarning",
    "SampledExcitation",
    "sample_excitation",
    "write_excitation_csv",
]

#: Samples per period of the highest harmonic below which the export is refused (20: the sampled sine
#: deviates from a linear interpolation by at most 1 - cos(pi / 20) = 1.2 % of its amplitude).
MIN_SAMPLES_PER_PERIOD = 20
#: A position or velocity sample closer to the robot's limit than (1 - this) of the half range (position)
#: or of the limit (velocity) warns. 0.98: within 2 %, i.e. 0.058 rad of a +-2.9 rad joint, closer than
#: the excitation's default margin of 0.1 rad. (The acceleration bound is the excitation's own design
#: bound, which an optimized trajectory touches by design: it is only enforced.)
WARN_FRACTION = 0.98

_UNITS = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2", "torque": "Nm"}


class ExcitationLimitError(ConfigError):
    """A sample of the exported excitation is beyond a limit.

    Attributes:
        joint: 0-based joint index (1-based with its name in the message); for ``"self-collision"`` the
            first link of the pair.
        quantity: ``"position"``, ``"velocity"``, ``"acceleration"``, ``"torque"``, ``"workspace"`` (height
            above the floor [m]) or ``"self-collision"`` (distance between links [m]).
        value: the worst sample's value; time: its time [s].
        limit: the limit it exceeds (the bound on the side it exceeds).
        excess: by how much it exceeds it (positive).
    """

    def __init__(
        self, message: str, *, joint: int, quantity: str, value: float, time: float, limit: float, excess: float
    ) -> None:
        super().__init__(message)
        self.joint = joint
        self.quantity = quantity
        self.value = value
        self.time = time
        self.limit = limit
        self.excess = excess


class ExcitationMarginWarning(UserWarning):
    """A sample of the exported excitation comes within ``1 - WARN_FRACTION`` of a limit."""


@dataclass(frozen=True)
class SampledExcitation:
    """The sampled excitation and its margins to the limits.

    Attributes:
        t: times (N,) [s]; q, dq, ddq: (N, n) [rad, rad/s, rad/s^2].
        joint_names: the robot's joints.
        rate: sampling rate [Hz].
        margins: per quantity, the smallest distance to the limit per joint (n,) (in the quantity's unit;
            negative: beyond).
        limits: per quantity, the (lower, upper) limits used per joint, each (n,).
        report: the worst sample of the torque, workspace and self-collision bounds
            (:meth:`~reflexarm.ident.excitation.limits.LimitEvaluator.report`).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    joint_names: tuple[str, ...]
    rate: float
    margins: dict[str, np.ndarray]
    limits: dict[str, tuple[np.ndarray, np.ndarray]]
    report: dict[str, dict[str, Any]] | None = None

    def margin_rows(self) -> list[dict[str, object]]:
        """Per joint (1-based), the smallest margin to each limit (for a printed table)."""
        rows: list[dict[str, object]] = []
        for j, name in enumerate(self.joint_names):
            row: dict[str, object] = {"joint": f"{j + 1} ({name})"}
            for quantity, m in self.margins.items():
                row[f"{quantity}_margin"] = float(m[j])
            rows.append(row)
        return rows


def sample_excitation(
    trajectory: FourierTrajectory,
    robot: RobotModel,
    *,
    rate: float,
    max_acceleration: npt.ArrayLike = DEFAULT_MAX_ACCELERATION,
    limits: ExcitationLimits | None = None,
) -> SampledExcitation:
    """Sample ``trajectory`` at ``rate`` [Hz] over its whole duration and check it against the limits.

    Args:
        trajectory: the excitation (its ``periods`` set the duration).
        robot: its position and velocity limits (infinite ones are not checked).
        rate: samples per second [Hz].
        max_acceleration: |ddq| bound per joint [rad/s^2] (robot files carry no acceleration limits;
            pass the excitation's own bound).
        limits: the torque, workspace and self-collision bounds (``design.limits``; default: the robot
            file's effort limits and the default floor, see the module docstring).

    Raises:
        ConfigError: a rate that is not positive or too low for the highest harmonic, or a trajectory of
            another number of joints.
        ExcitationLimitError: a sample beyond a limit (the worst one is named).

    Warns:
        ExcitationMarginWarning: a position or velocity sample within ``1 - WARN_FRACTION`` of a limit.
    """
    n = robot.n
    if trajectory.n != n:
        raise ConfigError(f"the excitation moves {trajectory.n} joints; robot {robot.name!r} has {n}")
    top_hz = trajectory.n_harmonics * trajectory.base_frequency_hz
    if not (np.isfinite(rate) and rate > 0):
        raise ConfigError(f"--rate must be a positive number of samples per second [Hz]; got {rate!r}")
    if rate < MIN_SAMPLES_PER_PERIOD * top_hz:
        raise ConfigError(
            f"rate {rate:g} Hz is too low for the excitation's highest harmonic at {top_hz:.4g} Hz: use at least "
            f"{MIN_SAMPLES_PER_PERIOD * top_hz:.4g} Hz ({MIN_SAMPLES_PER_PERIOD} samples per period of it)"
        )
    steps = int(np.floor(trajectory.duration * rate + 1e-9))
    t = np.arange(steps + 1) / rate
    q, dq, ddq = trajectory.evaluate(t)
    amax = np.broadcast_to(np.asarray(max_acceleration, dtype=float), (n,))
    vmax = robot.velocity_limit
    limits_used = {
        "position": (robot.lower_limit, robot.upper_limit),
        "velocity": (-vmax, vmax),
        "acceleration": (-amax, amax),
    }
    names = tuple(robot.joint_names)
    if limits is None:
        limits = excitation_limits(robot, max_acceleration=amax, position_margin=0.0, torque_fraction=1.0)[0]
    evaluator = LimitEvaluator(robot, limits, None)
    tau = evaluator.torque(q, dq, ddq)
    limits_used = dict(limits_used, torque=(-limits.max_torque, limits.max_torque))
    signals = {"position": q, "velocity": dq, "acceleration": ddq, "torque": tau}
    margins: dict[str, np.ndarray] = {}
    for quantity, x in signals.items():
        lo, hi = (np.asarray(b, dtype=float) for b in limits_used[quantity])
        margins[quantity] = _check_quantity(quantity, x, lo, hi, t, names)
    report = _check_geometry(robot, limits, t, q, dq, ddq)
    return SampledExcitation(t, q, dq, ddq, names, float(rate), margins, limits_used, report)


def _check_geometry(
    robot: RobotModel, limits: ExcitationLimits, t: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> dict[str, dict[str, Any]]:
    """The workspace and self-collision bounds on every sample; raises at the worst one beyond them."""
    from reflexarm.ident.excitation.limits import arm_geometry

    if limits.floor is None and not limits.self_collision:
        return {}
    geometry = arm_geometry(robot, 0.5 * (limits.lower + limits.upper), clearance=limits.clearance)
    report = LimitEvaluator(robot, replace(limits, max_torque=np.full(robot.n, np.inf)), geometry).report(t, q, dq, ddq)
    names = robot.joint_names
    ws = report.get("workspace")
    if ws is not None and float(ws["clearance_m"]) < 0:  # type: ignore[arg-type]
        j = int(ws["joint"])  # type: ignore[call-overload]
        depth = -float(ws["clearance_m"])  # type: ignore[arg-type]
        raise ExcitationLimitError(
            f"the link of joint {j + 1} ({names[j]}) goes {depth:.4g} m below the floor z = {limits.floor:g} m at "
            f"t = {float(ws['time']):.4g} s (workspace); re-run 'reflexarm excite' (it keeps the arm above the "
            "floor it is given with --floor)",
            joint=j, quantity="workspace", value=float(limits.floor) - depth,  # type: ignore[arg-type]
            time=float(ws["time"]), limit=float(limits.floor), excess=depth,  # type: ignore[arg-type]
        )  # fmt: skip
    sc = report.get("self_collision")
    if sc is not None and float(sc["clearance_m"]) < 0:  # type: ignore[arg-type]
        i, j = sc["pair"]  # type: ignore[misc]
        depth = -float(sc["clearance_m"])  # type: ignore[arg-type]
        raise ExcitationLimitError(
            f"the links of joints {i + 1} ({names[i]}) and {j + 1} ({names[j]}) overlap by {depth:.4g} m at "
            f"t = {float(sc['time']):.4g} s (self-collision, capsules fitted to the collision geometry); re-run "
            "'reflexarm excite', which keeps them apart",
            joint=int(i), quantity="self-collision", value=-depth, time=float(sc["time"]), limit=0.0, excess=depth,
        )  # fmt: skip
    return report


def _check_quantity(
    quantity: str, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, t: np.ndarray, names: tuple[str, ...]
) -> np.ndarray:
    """The smallest margin per joint of samples ``x`` (N, n) to [lo, hi]; raises at the worst sample beyond a
    finite limit and warns when a position or velocity comes within ``1 - WARN_FRACTION`` of it."""
    below, above = x - lo, hi - x  # distances inside the limits, (N, n)
    dist = np.minimum(below, above)
    margin = np.where(np.isfinite(lo) & np.isfinite(hi), dist.min(axis=0), np.inf)
    finite = np.isfinite(lo) & np.isfinite(hi) & (hi < 1e6)
    for j in np.flatnonzero(finite & (margin < 0)):
        k = int(np.argmin(dist[:, j]))
        upper = above[k, j] < below[k, j]
        limit = float(hi[j] if upper else lo[j])
        raise ExcitationLimitError(
            f"joint {j + 1} ({names[j]}) {quantity} {x[k, j]:.4g} {_UNITS[quantity]} at t = {t[k]:.4g} s is beyond "
            f"its {'upper' if upper else 'lower'} limit {limit:.4g} {_UNITS[quantity]} by {-dist[k, j]:.4g}; "
            "re-run 'reflexarm excite' with a larger --margin, lower --max-velocity/--max-acceleration or a "
            "lower --torque-fraction",
            joint=int(j),
            quantity=quantity,
            value=float(x[k, j]),
            time=float(t[k]),
            limit=limit,
            excess=float(-dist[k, j]),
        )
    half = 0.5 * (hi - lo)
    close = finite & (margin < (1.0 - WARN_FRACTION) * half) & (quantity in ("position", "velocity"))
    for j in np.flatnonzero(close):
        warnings.warn(
            f"joint {j + 1} ({names[j]}) {quantity} comes within {margin[j]:.4g} {_UNITS[quantity]} "
            f"of its limit (less than {100 * (1 - WARN_FRACTION):g} % of the half range {half[j]:.4g})",
            ExcitationMarginWarning,
            stacklevel=3,
        )
    return margin


def write_excitation_csv(sampled: SampledExcitation, path: str | os.PathLike[str]) -> Path:
    """Write ``t, position_<joint>..., velocity_<joint>..., acceleration_<joint>...`` (see the module docstring)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    names = sampled.joint_names
    header = ["t"] + [f"{kind}_{name}" for kind in ("position", "velocity", "acceleration") for name in names]
    data = np.column_stack([sampled.t, sampled.q, sampled.dq, sampled.ddq])
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows([f"{v:.10g}" for v in row] for row in data)
    return p
