"""The controller's edge: fault codes, plausibility bounds, timing statistics, input conversion.

Everything :meth:`reflexarm.control.Controller.step` receives is checked against the contract written
down in the :class:`~reflexarm.control.Controller` docstring, by the C++ core (``reflexarm._core``,
``cpp/src/contract.cpp``), which also writes the fault texts. This module holds the codes and signal ids the
core reports (the same numbers as ``reflexarm::FaultCode`` and ``reflexarm::Signal``), the bounds as a Python
dataclass, and the conversion of inputs that are not float64 arrays.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np

from reflexarm.errors import ConfigError, SignalError

__all__ = ["FAULT_CODES", "InputBounds", "TimingStats"]

# ---- fault codes of the tick (negative; 0: accepted), as reflexarm::FaultCode
BAD_SHAPE = -1  # a signal has the wrong length (raised as SignalError by the Python face)
NON_FINITE = -2  # signal[index] = value is NaN/inf
OUT_OF_BOUNDS = -3  # signal[index] = value outside [lo, hi]
TIME_NOT_INCREASING = -4  # t = value <= last accepted t = lo
MODEL_NON_FINITE = -5  # a Pinocchio term is NaN/inf
MASS_NOT_POSITIVE_DEFINITE = -6  # the damping update's Cholesky factorization failed
OBSERVER_INVALID = -7  # latched until reset
OUTPUT_NON_FINITE = -8  # the control law gave NaN/inf (never expected with accepted inputs); latches as -7

# ---- signal ids of a fault, as reflexarm::Signal
(SIG_T, SIG_Q, SIG_DQ, SIG_TAU_M, SIG_WRENCH, SIG_GRAVITY, SIG_Q_D, SIG_DQ_D, SIG_DDQ_D, SIG_MODEL, SIG_PERIOD) = range(
    11
)

#: Fault codes of :attr:`Command.fault_code` (0: no fault) and what they mean.
FAULT_CODES: dict[int, str] = {
    0: "none",
    NON_FINITE: "non-finite signal",
    OUT_OF_BOUNDS: "signal beyond its plausibility bound",
    TIME_NOT_INCREASING: "time stamp repeated or going backwards",
    MODEL_NON_FINITE: "non-finite dynamics terms of the model",
    MASS_NOT_POSITIVE_DEFINITE: "mass matrix not positive definite",
    OBSERVER_INVALID: "observer state invalid (latched until reset)",
    OUTPUT_NON_FINITE: "non-finite control law (latched until reset, as an invalid observer)",
}

#: Signal names as in the fault texts, by signal id.
SIGNAL_NAMES = {
    SIG_T: "measurement t",
    SIG_Q: "measurement q",
    SIG_DQ: "measurement dq",
    SIG_TAU_M: "measurement tau_m",
    SIG_WRENCH: "measurement wrench",
    SIG_GRAVITY: "measurement gravity",
    SIG_Q_D: "reference q_d",
    SIG_DQ_D: "reference dq_d",
    SIG_DDQ_D: "reference ddq_d",
    SIG_MODEL: "model",
    SIG_PERIOD: "update period",
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


def timing_stats(raw: tuple[int, float, float, float, int, float, float]) -> TimingStats:
    """TimingStats from the core's ``timing`` tuple (n_periods, sum, min, max, clipped, band_low, band_high)."""
    count, total, lo, hi, clipped, band_lo, band_hi = raw
    nan = math.nan
    return TimingStats(
        int(count),
        float(total) / count if count else nan,
        float(lo) if count else nan,
        float(hi) if count else nan,
        int(clipped),
        (float(band_lo), float(band_hi)),
    )


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
    if arr.dtype == np.float64 and arr.flags.c_contiguous:
        return arr  # read-only or not: the tick takes it as it is
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


def shape_error(signal: int, received: int, expected: int) -> SignalError:
    """The SignalError for a BAD_SHAPE fault of the tick (signal id, received length, expected length)."""
    return SignalError(SIGNAL_NAMES[signal], f"shape ({received},)", f"a real vector of shape ({expected},)")


def signal_bounds(
    bounds: tuple[np.ndarray, ...], input_bounds: InputBounds, g_norm: float
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The plausibility bounds per signal as (low, high) arrays, from the core's per-joint ``bounds``
    (q_lo, q_hi, dq_max, ddq_max, tau_m_max, ...), the InputBounds and the model's |gravity|."""
    q_lo, q_hi, dq, ddq, tau_m = (np.array(b, dtype=float) for b in bounds[:5])
    b = input_bounds
    wrench = np.array([b.max_force] * 3 + [b.max_moment] * 3)
    g_lo, g_hi = max(g_norm - b.gravity_tolerance, 0.0), g_norm + b.gravity_tolerance
    return {
        "q": (q_lo, q_hi),
        "q_d": (q_lo.copy(), q_hi.copy()),
        "dq": (-dq, dq),
        "dq_d": (-dq, dq.copy()),
        "ddq_d": (-ddq, ddq),
        "tau_m": (-tau_m, tau_m),
        "wrench": (-wrench, wrench),
        "|gravity|": (np.array([g_lo]), np.array([g_hi])),
    }
