"""Construction-time pieces of :class:`reflexarm.control.Controller`: the period band, the torque limit, the
C++ core (``reflexarm._core``) and the parameters it is configured with."""

from __future__ import annotations

import importlib
import math
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_positive_scalar, as_switch, as_vector
from reflexarm.errors import ConfigError, ReflexArmError
from reflexarm.robots.robot_model import RobotModel


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


class DetectionFriction(TypedDict):
    """:class:`~reflexarm.control.Controller` keywords of the detection observer's friction model."""

    detection_kappa_f: int
    detection_friction_velocity_band: float | None


def detection_friction(band: float | None) -> DetectionFriction:
    """The :class:`~reflexarm.control.Controller` keywords of the detection observer's own friction model in the
    velocity band ``band`` [rad/s] (``detection_kappa_f=1``), or of none (``band`` None: it follows kappa_f)."""
    return {"detection_kappa_f": int(band is not None), "detection_friction_velocity_band": band}


def check_detection_friction(kappa_f: object, band: object, has_observer: bool) -> tuple[int, float | None]:
    """``Controller``'s (detection_kappa_f, detection_friction_velocity_band), checked: the friction model needs a
    detection observer, and a band needs that friction model (no silently unused setting)."""
    switch = as_switch(kappa_f, "detection_kappa_f")
    if switch and not has_observer:
        raise ConfigError("detection_kappa_f = 1 needs a detection observer (detection_observer_gain)")
    if band is None:
        return switch, None
    if not switch:
        raise ConfigError(
            "detection_friction_velocity_band is the band of detection_kappa_f = 1's friction model; give "
            "detection_kappa_f=1 with it"
        )
    return switch, as_positive_scalar(band, "detection_friction_velocity_band")


#: A detector slower than this (its time scale 1/k_o + 1/K_f, per joint) gets a warning [s]: five times the paper's
#: 5 1/s observer (0.2 s) and twice the reaction guard's 0.5 s. A contact shorter than the time scale reaches the
#: detector at a fraction of its size, so a much slower detector is detection practically off for most contacts.
SLOW_DETECTOR_S = 1.0


def warn_slow_detector(observer_gain: np.ndarray, filter_gain: np.ndarray | None, names: Sequence[str]) -> None:
    """A UserWarning when the detector's time scale ``1/k_o (+ 1/K_f)`` exceeds SLOW_DETECTOR_S on some joint
    (``observer_gain``: the detecting observer's, per joint; ``filter_gain``: the second stage's, or None)."""
    scale = 1.0 / np.asarray(observer_gain, dtype=float)
    if filter_gain is not None:
        scale = scale + 1.0 / np.asarray(filter_gain, dtype=float)
    slow = np.flatnonzero(scale > SLOW_DETECTOR_S)
    if slow.size:
        joints = [names[int(i)] for i in slow]
        warnings.warn(
            f"the collision detector's time scale (1/k_o + 1/K_f) is {float(scale.max()):.3g} s on joint(s) "
            f"{joints} (more than {SLOW_DETECTOR_S:g} s): a contact shorter than that reaches the detector at a "
            "fraction of its size, so most contacts go undetected; raise the detection observer's gain or the second "
            "stage's (detection_observer_gain, detection_filter_gain)",
            UserWarning,
            stacklevel=3,  # the caller of Controller(...)
        )
