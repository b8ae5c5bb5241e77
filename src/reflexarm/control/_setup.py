"""Construction-time pieces of :class:`reflexarm.control.Controller`: the period band, the torque limit, the
C++ core (``reflexarm._core``) and the parameters it is configured with."""

from __future__ import annotations

import importlib
import math
import warnings
from collections.abc import Sequence
from dataclasses import fields
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_vector
from reflexarm.errors import ConfigError, ReflexArmError
from reflexarm.robots.robot_model import RobotModel

if TYPE_CHECKING:
    from reflexarm.control.controller import Controller


def check_period_band(
    band: object, dt: float, observer_gains: Sequence[np.ndarray], *, exact: bool = False
) -> tuple[float, float]:
    """(low, high) multiples of dt with 0 < low <= 1 <= high, and (Euler observer, ``exact=False``)
    k_o * dt * high < 1 for every observer."""
    try:
        lo, hi = (float(x) for x in band)  # type: ignore[attr-defined]
    except (TypeError, ValueError) as e:
        raise ConfigError(f"period_band must be (low, high) multiples of dt; got {band!r}") from e
    if not (0.0 < lo <= 1.0 <= hi < math.inf):
        raise ConfigError(f"period_band must satisfy 0 < low <= 1 <= high < inf; got {band!r}")
    k_o = max(float(np.max(k)) for k in observer_gains)
    if not exact and k_o * dt * hi >= 1.0:
        raise ConfigError(
            f"observer_gain * dt * period_band[1] must be < 1 for the observer to stay stable at the longest "
            f"integrated period; got {k_o} 1/s * {dt} s * {hi} (observer_discretization='exact' is stable at "
            "any gain)"
        )
    return lo, hi


def check_discretization(name: object, choices: Sequence[str]) -> str:
    """``name`` if it is one of the observer discretizations ``choices``, else a ConfigError naming them."""
    if name not in choices:
        raise ConfigError(f"unknown observer_discretization {name!r}; choose one of: {', '.join(choices)}")
    return str(name)


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


def load_core() -> ModuleType:
    """The compiled module ``reflexarm._core`` (built by ``make install``), or an error saying how to get it."""
    try:
        return importlib.import_module("reflexarm._core")
    except ImportError as e:
        raise ReflexArmError(
            f"reflexarm's C++ core (module reflexarm._core) cannot be imported ({e}); expected it built and "
            "installed by `make install` (needs cmake >= 3.18 and a C++17 compiler)"
        ) from e


def core_params(ctrl: Controller, core: ModuleType) -> Any:
    """The core's ControllerParams for a Controller whose Python-side checks have passed."""
    p = core.ControllerParams()
    robot, imp = ctrl.robot, ctrl.impedance
    p.stiffness, p.damping_ratio = imp.gains.stiffness.copy(), imp.gains.damping_ratio.copy()
    p.observer_gain = ctrl.observer.observer_gain.copy()
    det = ctrl.detection_observer
    p.detection_observer_gain = np.zeros(0) if det is None else det.observer_gain.copy()
    p.threshold = np.zeros(0) if ctrl.detector is None else ctrl.detector.threshold.copy()
    p.reaction = ctrl.reaction
    p.contact_reaction = ctrl.contact_reaction
    p.reaction_params = ctrl.reaction_settings.to_core(core)
    p.observer_discretization = ctrl.observer_discretization
    p.kappa_f, p.kappa_eps, p.kappa_ext = ctrl._kappa_init
    p.residual_limit, p.switch_time, p.dt = ctrl.residual_limit, ctrl.switch_time, ctrl.dt
    p.damping_update_period = imp.damping_update_period
    fr = robot.friction
    p.friction_coulomb, p.friction_viscous = fr.coulomb.copy(), fr.viscous.copy()
    p.friction_velocity_band = fr.velocity_band
    if robot.has_springs:
        p.spring_stiffness = np.array(robot.spring_stiffness, dtype=float)
        p.spring_reference = np.array(robot.spring_reference, dtype=float)
    p.sensor_frame_id = robot.sensor_frame_id
    p.torque_limit = ctrl.torque_limit.copy()
    p.torque_rate_limit = np.zeros(0) if ctrl.torque_rate_limit is None else ctrl.torque_rate_limit.copy()
    bounds = core.InputBounds()
    for f in fields(ctrl.input_bounds):
        setattr(bounds, f.name, getattr(ctrl.input_bounds, f.name))
    p.input_bounds = bounds
    p.period_band_low, p.period_band_high = ctrl.period_band
    return p
