"""What the tests expect of the controller's fault texts and event records (``controller_oracle``'s helpers): the
fault text of a contract violation written from the contract, and the fields of an event record that differ."""

from __future__ import annotations

import numpy as np

from reflexarm.control.contract import (
    MASS_NOT_POSITIVE_DEFINITE,
    MODEL_NON_FINITE,
    NON_FINITE,
    OBSERVER_INVALID,
    OUT_OF_BOUNDS,
    OUTPUT_NON_FINITE,
    SIG_DDQ_D,
    SIG_DQ,
    SIG_DQ_D,
    SIG_GRAVITY,
    SIG_MODEL,
    SIG_Q,
    SIG_Q_D,
    SIG_T,
    SIG_TAU_M,
    SIG_WRENCH,
    TIME_NOT_INCREASING,
)

_SIGNALS = {  # name, unit
    SIG_T: ("measurement t", "s"),
    SIG_Q: ("measurement q", "rad"),
    SIG_DQ: ("measurement dq", "rad/s"),
    SIG_TAU_M: ("measurement tau_m", "Nm"),
    SIG_WRENCH: ("measurement wrench", "N or Nm"),
    SIG_GRAVITY: ("measurement gravity", "m/s^2"),
    SIG_Q_D: ("reference q_d", "rad"),
    SIG_DQ_D: ("reference dq_d", "rad/s"),
    SIG_DDQ_D: ("reference ddq_d", "rad/s^2"),
    SIG_MODEL: ("model", ""),
}
_BOUND_NAMES = {  # which InputBounds field sets the bound
    SIG_Q: "joint limits +- InputBounds.position_margin",
    SIG_Q_D: "joint limits +- InputBounds.position_margin",
    SIG_DQ: "InputBounds.velocity_factor x velocity limit",
    SIG_DQ_D: "InputBounds.velocity_factor x velocity limit",
    SIG_TAU_M: "InputBounds.torque_factor x torque limit",
    SIG_DDQ_D: "InputBounds.max_acceleration",
    SIG_GRAVITY: "model gravity +- InputBounds.gravity_tolerance",
}


def expected_text(fault: tuple) -> str:
    """The fault text the contract documents for (code, signal, index, value, lo, hi), written here from the
    contract's wording (the core writes its own in cpp/src/fault.cpp)."""
    code, signal, index, value, lo, hi = fault
    value, lo, hi = float(value), float(lo), float(hi)
    name, unit = _SIGNALS.get(signal, ("input", ""))
    where = f"{name}[{index}]" if index >= 0 else name
    if code == NON_FINITE:
        return f"non-finite {where} = {value!r}"
    if code == OUT_OF_BOUNDS:
        if signal == SIG_WRENCH:
            bound = "InputBounds.max_force" if index < 3 else "InputBounds.max_moment"
            unit = "N" if index < 3 else "Nm"
        elif signal == SIG_GRAVITY:
            where = f"|{name}|"
            bound = _BOUND_NAMES[signal]
        else:
            bound = _BOUND_NAMES.get(signal, "bound")
        return f"{where} = {value:.6g} {unit} outside the plausible [{lo:.6g}, {hi:.6g}] {unit} ({bound})"
    if code == TIME_NOT_INCREASING:
        return (
            f"measurement t = {value!r} s does not advance past the last accepted t = {lo!r} s "
            "(repeated or backwards time stamp)"
        )
    if code == MODEL_NON_FINITE:
        return "non-finite model terms (gravity, Coriolis, momentum or feed-forward) at this state"
    if code == MASS_NOT_POSITIVE_DEFINITE:
        return "mass matrix of the model not positive definite at this q; damping not updated"
    if code == OBSERVER_INVALID:
        return "observer state invalid (non-finite): collision detection is off until reset()"
    if code == OUTPUT_NON_FINITE:
        return f"non-finite control law on joint {index}: collision detection is off until reset()"
    return f"fault {code}"


#: Event fields that are arrays, times or energies (compared with a tolerance); the others compare exactly.
EVENT_ARRAYS = ("residual", "q_detect", "q_target")


def event_mismatches(want: dict | None, got: dict, atol: float) -> list[str]:
    """The fields of an event record (the core's dict, or the Python CollisionEvent as one with a 0/1 joint mask)
    that differ from the oracle's: arrays and floats beyond ``atol`` (NaN equals NaN), the rest exactly."""
    if want is None:
        return [] if not got["detected"] else ["detected: core True, oracle False"]
    bad = []
    for key, w in want.items():
        g = got[key]
        if key == "joints":
            same = np.array_equal(np.asarray(g).astype(bool), w)
        elif key in EVENT_ARRAYS or isinstance(w, float):
            a, b = np.asarray(g, dtype=float), np.asarray(w, dtype=float)
            same = a.shape == b.shape and bool(np.all((np.abs(a - b) <= atol) | (np.isnan(a) & np.isnan(b))))
        else:
            same = g == w
        if not same:
            bad.append(f"{key}: core {g!r}, oracle {w!r}")
    return bad
