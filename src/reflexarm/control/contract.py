"""The controller's edge: plausibility bounds, fault descriptions, timing statistics, input conversion.

Everything :meth:`reflexarm.control.Controller.step` receives is checked against the contract written
down in the :class:`~reflexarm.control.Controller` docstring. The bounds are plain data (arrays and
scalars in the compiled tick's ``work`` array) and the faults are integer codes
(:mod:`reflexarm.control._kernels`), so the same contract can be carried into a C++ tick.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np

from reflexarm.control import _kernels as _k
from reflexarm.errors import ConfigError, SignalError

__all__ = ["FAULT_CODES", "InputBounds", "TimingStats"]

#: Fault codes of :attr:`Command.fault_code` (0: no fault) and what they mean.
FAULT_CODES: dict[int, str] = {
    0: "none",
    _k.NON_FINITE: "non-finite signal",
    _k.OUT_OF_BOUNDS: "signal beyond its plausibility bound",
    _k.TIME_NOT_INCREASING: "time stamp repeated or going backwards",
    _k.MODEL_NON_FINITE: "non-finite dynamics terms of the model",
    _k.MASS_NOT_POSITIVE_DEFINITE: "mass matrix not positive definite",
    _k.OBSERVER_INVALID: "observer state invalid (latched until reset)",
    _k.OUTPUT_NON_FINITE: "non-finite control law (latched until reset, as an invalid observer)",
}

_SIGNALS = {
    _k.SIG_T: ("measurement t", "s"),
    _k.SIG_Q: ("measurement q", "rad"),
    _k.SIG_DQ: ("measurement dq", "rad/s"),
    _k.SIG_TAU_M: ("measurement tau_m", "Nm"),
    _k.SIG_WRENCH: ("measurement wrench", "N or Nm"),
    _k.SIG_GRAVITY: ("measurement gravity", "m/s^2"),
    _k.SIG_Q_D: ("reference q_d", "rad"),
    _k.SIG_DQ_D: ("reference dq_d", "rad/s"),
    _k.SIG_DDQ_D: ("reference ddq_d", "rad/s^2"),
    _k.SIG_MODEL: ("model", ""),
}
# which InputBounds field sets the bound of each signal (named in the fault text)
_BOUND_NAMES = {
    _k.SIG_Q: "joint limits +- InputBounds.position_margin",
    _k.SIG_Q_D: "joint limits +- InputBounds.position_margin",
    _k.SIG_DQ: "InputBounds.velocity_factor x velocity limit",
    _k.SIG_DQ_D: "InputBounds.velocity_factor x velocity limit",
    _k.SIG_TAU_M: "InputBounds.torque_factor x torque limit",
    _k.SIG_DDQ_D: "InputBounds.max_acceleration",
    _k.SIG_GRAVITY: "model gravity +- InputBounds.gravity_tolerance",
}


@dataclass(frozen=True)
class InputBounds:
    """Plausibility bounds of the controller's inputs; a value beyond one makes the tick a fault.

    The bounds are wide on purpose: they reject glitches and garbage (a +10 rad jump, 1e200), never
    sensor noise (the simulated plant's noise even at 30x the paper's levels stays far inside them).

    Attributes:
        position_margin: q and q_d may exceed the model's joint limits by this much [rad] (joints without
            finite limits are only checked for finiteness).
        velocity_factor: |dq| and |dq_d| up to this multiple of the model's velocity limit [-]. Wide
            because a plant without actuator dynamics (an ideal simulation) spins a light wrist to ~4x its
            velocity limit within one tick of a 30 Nm step.
        torque_factor: |tau_m| up to this multiple of the controller's torque limit (the saturation, or
            the model's effort limit when saturation is off) [-].
        max_force: |wrist force component| bound [N].
        max_moment: |wrist moment component| bound [Nm].
        gravity_tolerance: accepted deviation of the measured |gravity| from the model's [m/s^2].
        max_acceleration: |ddq_d| bound [rad/s^2].
        max_velocity: |dq| bound for joints without a finite positive velocity limit [rad/s].
        max_torque: |tau_m| bound for joints without a finite positive torque limit [Nm].
    """

    position_margin: float = 0.2
    velocity_factor: float = 10.0
    torque_factor: float = 3.0
    max_force: float = 2000.0
    max_moment: float = 200.0
    gravity_tolerance: float = 1.0
    max_acceleration: float = 1000.0
    max_velocity: float = 100.0
    max_torque: float = 1e4

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not ok or not math.isfinite(float(value)) or float(value) <= 0.0:
                raise ConfigError(f"InputBounds.{f.name} must be a finite positive number; got {value!r}")
            object.__setattr__(self, f.name, float(value))


class TimingStats(NamedTuple):
    """Statistics of the measured control periods since the last reset (accepted ticks only).

    Attributes:
        n_periods: number of measured periods (accepted ticks after the first).
        mean_period, min_period, max_period: of the measured periods [s] (NaN while n_periods is 0).
        clipped: periods outside the accepted band, integrated at the band's edge instead.
        band: the band (low, high) the observer integrates within [s].
    """

    n_periods: int
    mean_period: float
    min_period: float
    max_period: float
    clipped: int
    band: tuple[float, float]


def timing_stats(work: np.ndarray) -> TimingStats:
    """Read the timing statistics from the compiled tick's ``work`` array."""
    count = int(work[_k.T_COUNT])
    nan = math.nan
    return TimingStats(
        count,
        float(work[_k.T_SUM]) / count if count else nan,
        float(work[_k.T_MIN]) if count else nan,
        float(work[_k.T_MAX]) if count else nan,
        int(work[_k.T_CLIPPED]),
        (float(work[_k.PERIOD_LO]), float(work[_k.PERIOD_HI])),
    )


def describe_fault(code: int, work: np.ndarray) -> str:
    """Human-readable text of a fault code with its details (signal, component, value, bound)."""
    signal = int(work[_k.F_SIGNAL])
    index = int(work[_k.F_INDEX])
    value, lo, hi = float(work[_k.F_VALUE]), float(work[_k.F_LO]), float(work[_k.F_HI])
    name, unit = _SIGNALS.get(signal, ("input", ""))
    where = f"{name}[{index}]" if index >= 0 else name
    if code == _k.NON_FINITE:
        return f"non-finite {where} = {value!r}"
    if code == _k.OUT_OF_BOUNDS:
        if signal == _k.SIG_WRENCH:
            bound = "InputBounds.max_force" if index < 3 else "InputBounds.max_moment"
            unit = "N" if index < 3 else "Nm"
        elif signal == _k.SIG_GRAVITY:
            where = f"|{name}|"
            bound = _BOUND_NAMES[signal]
        else:
            bound = _BOUND_NAMES.get(signal, "bound")
        return f"{where} = {value:.6g} {unit} outside the plausible [{lo:.6g}, {hi:.6g}] {unit} ({bound})"
    if code == _k.TIME_NOT_INCREASING:
        return (
            f"measurement t = {value!r} s does not advance past the last accepted t = {lo!r} s "
            "(repeated or backwards time stamp)"
        )
    if code == _k.MODEL_NON_FINITE:
        return "non-finite model terms (gravity, Coriolis, momentum or feed-forward) at this state"
    if code == _k.MASS_NOT_POSITIVE_DEFINITE:
        return "mass matrix of the model not positive definite at this q; damping not updated"
    if code == _k.OBSERVER_INVALID:
        return "observer state invalid (non-finite): collision detection is off until reset()"
    if code == _k.OUTPUT_NON_FINITE:
        return f"non-finite control law on joint {index}: collision detection is off until reset()"
    return f"fault {code}"


def _as_time(value: object) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.ndarray)):
        raise SignalError("measurement t", type(value).__name__, "a real number [s]")
    arr = np.asarray(value)
    if arr.shape != () or arr.dtype.kind not in "fiu":
        raise SignalError("measurement t", f"{arr.dtype} array of shape {arr.shape}", "a real number [s]")
    return float(arr)


def as_signal(value: object, length: int, name: str) -> np.ndarray:
    """``value`` as a contiguous float64 vector of ``length``; SignalError naming ``name`` otherwise.

    Integer and other float dtypes and lists are converted; complex, bool, str and object values and
    wrong shapes are programming errors and raise.
    """
    expected = f"a real vector of shape ({length},)"
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as e:  # ragged lists and the like
        raise SignalError(name, type(value).__name__, expected) from e
    if arr.dtype.kind not in "fiu":
        raise SignalError(name, f"dtype {arr.dtype}", expected, "complex, bool, str and object values are refused")
    if arr.shape != (length,):
        raise SignalError(name, f"shape {arr.shape}", expected)
    if arr.dtype == np.float64:
        return arr  # any layout, read-only or not: the tick takes it as it is
    return np.ascontiguousarray(arr, dtype=np.float64)


def convert_inputs(measurement: Any, reference: Any, n: int) -> tuple[tuple[Any, ...], bool]:
    """Unpack and convert a measurement and a reference to the tick's types, or raise SignalError.

    Returns the nine values (t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) and whether any array had
    to be converted (False: every one was a float64 array already and is returned as is).
    """
    try:
        t, q, dq, tau_m, wrench, gravity = measurement
    except (TypeError, ValueError) as e:
        raise SignalError(
            "measurement", type(measurement).__name__, "a Measurement(t, q, dq, tau_m, wrench, gravity)"
        ) from e
    try:
        q_d, dq_d, ddq_d = reference
    except (TypeError, ValueError) as e:
        raise SignalError("reference", type(reference).__name__, "a Reference(q_d, dq_d, ddq_d)") from e
    raw = (q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d)
    names = ("q", "dq", "tau_m", "wrench", "gravity", "q_d", "dq_d", "ddq_d")
    lengths = (n, n, n, 6, 3, n, n, n)
    arrays = tuple(
        as_signal(v, length, f"{'reference' if i > 4 else 'measurement'} {name}")
        for i, (v, length, name) in enumerate(zip(raw, lengths, names, strict=True))
    )
    converted = any(a is not v for a, v in zip(arrays, raw, strict=True))
    return (_as_time(t), *arrays), converted


def shape_error(work: np.ndarray) -> SignalError:
    """The SignalError for a BAD_SHAPE code of the tick."""
    name, _ = _SIGNALS[int(work[_k.F_SIGNAL])]
    return SignalError(name, f"shape ({int(work[_k.F_VALUE])},)", f"a real vector of shape ({int(work[_k.F_HI])},)")


def signal_bounds(work: np.ndarray, rows: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The plausibility bounds per signal as (low, high) arrays, read from the tick's ``work`` array."""
    dq, ddq, tau_m = rows[_k.DQ_MAX_ROW].copy(), rows[_k.DDQ_MAX_ROW].copy(), rows[_k.TAU_M_MAX_ROW].copy()
    wrench = np.array([work[_k.FORCE_MAX]] * 3 + [work[_k.MOMENT_MAX]] * 3)
    g_lo, g_hi = max(work[_k.G_NORM] - work[_k.G_TOL], 0.0), work[_k.G_NORM] + work[_k.G_TOL]
    q = rows[_k.Q_LO_ROW].copy(), rows[_k.Q_HI_ROW].copy()
    return {
        "q": q,
        "q_d": q,
        "dq": (-dq, dq),
        "dq_d": (-dq, dq),
        "ddq_d": (-ddq, ddq),
        "tau_m": (-tau_m, tau_m),
        "wrench": (-wrench, wrench),
        "|gravity|": (np.array([g_lo]), np.array([g_hi])),
    }
