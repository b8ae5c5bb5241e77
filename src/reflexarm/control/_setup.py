"""Construction-time pieces of :class:`reflexarm.control.Controller`: the period band, the torque limit and
the compiled tick's ``work`` array (parameters and plausibility bounds, see :mod:`._kernels`)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_vector
from reflexarm.control import _kernels as _k
from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

if TYPE_CHECKING:
    from reflexarm.control.controller import Controller


def check_period_band(band: object, dt: float, observer_gains: Sequence[np.ndarray]) -> tuple[float, float]:
    """(low, high) multiples of dt with 0 < low <= 1 <= high, and k_o * dt * high < 1 for every observer."""
    try:
        lo, hi = (float(x) for x in band)  # type: ignore[attr-defined]
    except (TypeError, ValueError) as e:
        raise ConfigError(f"period_band must be (low, high) multiples of dt; got {band!r}") from e
    if not (0.0 < lo <= 1.0 <= hi < math.inf):
        raise ConfigError(f"period_band must satisfy 0 < low <= 1 <= high < inf; got {band!r}")
    k_o = max(float(np.max(k)) for k in observer_gains)
    if k_o * dt * hi >= 1.0:
        raise ConfigError(
            f"observer_gain * dt * period_band[1] must be < 1 for the observer to stay stable at the longest "
            f"integrated period; got {k_o} 1/s * {dt} s * {hi}"
        )
    return lo, hi


def resolve_torque_limit(robot: RobotModel, torque_limit: npt.ArrayLike | str | None) -> np.ndarray:
    """The saturation per joint [Nm] (inf: none) from ``"model"``, ``None`` or a positive value."""
    n = robot.n
    if torque_limit is None:
        return np.full(n, np.inf)
    if isinstance(torque_limit, str):
        if torque_limit != "model":
            raise ConfigError(f"torque_limit must be 'model', None or a positive value; got {torque_limit!r}")
        effort = np.asarray(robot.effort_limit, dtype=float).copy()
        missing = ~(np.isfinite(effort) & (effort > 0.0))
        if np.any(missing):
            names = [robot.joint_names[i] for i in np.flatnonzero(missing)]
            warnings.warn(
                f"robot {robot.name!r} has no finite positive effort limit for joint(s) {names} "
                f"(got {effort[missing].tolist()}): their torque is not saturated; pass torque_limit= [Nm] "
                "to bound it",
                UserWarning,
                stacklevel=3,  # the caller of Controller(...)
            )
            effort[missing] = np.inf
        return effort
    return as_vector(torque_limit, n, "torque_limit", positive=True)


def fill_work(ctrl: Controller) -> None:
    """Write the controller's parameters and plausibility bounds into its ``work`` array."""
    w, rows, b, robot, dt = ctrl._work, ctrl._rows, ctrl.input_bounds, ctrl.robot, ctrl.dt
    w[_k.N_JOINTS] = ctrl.n
    w[_k.DT] = dt
    w[_k.PERIOD_LO], w[_k.PERIOD_HI] = ctrl.period_band[0] * dt, ctrl.period_band[1] * dt
    w[_k.INV_BAND] = 1.0 / robot.friction.velocity_band
    w[_k.LIMIT] = ctrl.residual_limit
    w[_k.USE_DET] = float(ctrl.detection_observer is not None)
    w[_k.G_NORM] = float(np.linalg.norm(ctrl._gravity))
    w[_k.G_TOL] = b.gravity_tolerance
    w[_k.FORCE_MAX], w[_k.MOMENT_MAX] = b.max_force, b.max_moment
    rows[_k.K_ROW] = ctrl.impedance.gains.stiffness
    rows[_k.DAMPING_RATIO_ROW] = ctrl.impedance.gains.damping_ratio
    rows[_k.KO_ROW] = ctrl.observer.observer_gain
    if ctrl.detection_observer is not None:
        rows[_k.KO_DET_ROW] = ctrl.detection_observer.observer_gain
    rows[_k.THRESHOLD_ROW] = np.inf if ctrl.detector is None else ctrl.detector.threshold
    rows[_k.COULOMB_ROW] = robot.friction.coulomb
    rows[_k.VISCOUS_ROW] = robot.friction.viscous
    lower = np.asarray(robot.lower_limit, dtype=float)
    upper = np.asarray(robot.upper_limit, dtype=float)
    rows[_k.Q_LO_ROW] = np.where(np.isfinite(lower), lower - b.position_margin, -np.inf)
    rows[_k.Q_HI_ROW] = np.where(np.isfinite(upper), upper + b.position_margin, np.inf)
    vel = np.asarray(robot.velocity_limit, dtype=float)
    rows[_k.DQ_MAX_ROW] = np.where(np.isfinite(vel) & (vel > 0), b.velocity_factor * vel, b.max_velocity)
    rows[_k.DDQ_MAX_ROW] = b.max_acceleration
    # tau_m is judged against the saturation, or the model's effort limit when saturation is off
    ref = np.where(np.isfinite(ctrl.torque_limit), ctrl.torque_limit, np.asarray(robot.effort_limit, dtype=float))
    ok = np.isfinite(ref) & (ref > 0)
    rows[_k.TAU_M_MAX_ROW] = np.where(ok, b.torque_factor * np.where(ok, ref, 1.0), b.max_torque)
    rows[_k.TAU_MAX_ROW] = ctrl.torque_limit
    rate = ctrl.torque_rate_limit
    rows[_k.TAU_STEP_ROW] = np.inf if rate is None else rate * dt
