"""Detection delays implied by a threshold: a torque step at a joint, or a force step at the end effector.

The observer's residual follows an external torque step s with the first-order response (8),
r(t) = b + s (1 - exp(-t / T_o)), T_o = -dt / ln(1 - k_o dt) (the discrete observer's time constant,
1/k_o to 0.3 % for k_o dt <= 0.005), b the residual before the step. It reaches zeta at

    t_d = -T_o ln(1 - (zeta - b) / s)      (never if s <= zeta - b; 0 if b >= zeta).

With a second stage of time constant T_f = 1/K_f on the residual (``Controller(detection_filter_gain=)``), the
detector sees the cascade of real poles -1/T_1 and -1/T_2 (T_1 = T_o, T_2 = T_f), whose unit step and ramp
responses are

    step(t) = 1 - (T_1 e^{-t/T_1} - T_2 e^{-t/T_2}) / (T_1 - T_2),
    ramp(t) = t - (T_1 + T_2) + (T_1^2 e^{-t/T_1} - T_2^2 e^{-t/T_2}) / (T_1 - T_2),

(equal poles, T_1 = T_2 = T: 1 - (1 + t/T) e^{-t/T} and t - 2T + (2T + t) e^{-t/T}); the crossing times are their
roots (Brent's method). A force F at the end effector reaches the joints as tau = J_v(q)^T F (J_v: the linear
rows of the end-effector Jacobian, world-aligned); the arm detects it at the first joint whose |tau_j| crosses.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

__all__ = ["FORCE_DIRECTIONS", "detection_delay", "force_step_delays", "ramp_lag", "ramp_response", "step_response"]

#: The directions of the end-effector force step: the base frame's axes, both signs.
FORCE_DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


#: Relative difference of the two time constants at or below which the equal-poles forms are used, at their mean
#: (the general forms tend to them; the responses are symmetric in T_1, T_2, so the mean's error is of the order of
#: the relative difference squared, 1e-18, below round-off).
EQUAL_POLES = 1e-9
#: Tolerance of the root finding, in multiples of the sum of the time constants (far below a period).
ROOT_XTOL = 1e-12


def _check_time_constants(time_constant: float, filter_time_constant: float | None) -> None:
    for name, v in (("time_constant", time_constant), ("filter_time_constant", filter_time_constant)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be a finite time constant > 0 [s]; got {v!r}")


def _equal(t1: float, t2: float) -> bool:
    return abs(t1 - t2) <= EQUAL_POLES * max(t1, t2)


def _divided(t: float, t1: float, t2: float) -> tuple[float, float]:
    """(T_1 e^{-t/T_1} - T_2 e^{-t/T_2}) / (T_1 - T_2) and (T_1^2 e^{-t/T_1} - T_2^2 e^{-t/T_2}) / (T_1 - T_2) at
    ``t`` [s], T_1 != T_2. With x = t (T_1 - T_2) / (T_1 T_2) they are e^{-t/T_2} (1 + (t/T_2) E) and
    e^{-t/T_2} (T_1 + T_2 + T_1 (t/T_2) E), E = (e^x - 1) / x: free of the cancellation of the differences for
    near-equal poles (|x| <= 1); the differences themselves lose less than a digit beyond."""
    x = t * (t1 - t2) / (t1 * t2)
    if abs(x) > 1.0:
        e1, e2 = math.exp(-t / t1), math.exp(-t / t2)
        return (t1 * e1 - t2 * e2) / (t1 - t2), (t1 * t1 * e1 - t2 * t2 * e2) / (t1 - t2)
    e2, r = math.exp(-t / t2), t / t2 * (math.expm1(x) / x if x != 0.0 else 1.0)
    return e2 * (1.0 + r), e2 * (t1 + t2 + t1 * r)


def step_response(t: float, time_constant: float, filter_time_constant: float | None = None) -> float:
    """The detector's residual at ``t`` [s] after a unit step of external torque, from rest: 1 - e^{-t/T_1} for
    the observer alone (``filter_time_constant`` None), else the cascade's (module docstring)."""
    t1, t2 = time_constant, filter_time_constant
    if t2 is None:
        return -math.expm1(-t / t1)
    if _equal(t1, t2):
        tm = 0.5 * (t1 + t2)
        return 1.0 - (1.0 + t / tm) * math.exp(-t / tm)
    return 1.0 - _divided(t, t1, t2)[0]


def _catch_up(t: float, t1: float, t2: float) -> float:
    """The cascade's ramp response minus its asymptote t - (T_1 + T_2), at ``t`` [s] (module docstring)."""
    if _equal(t1, t2):
        tm = 0.5 * (t1 + t2)
        return (2.0 * tm + t) * math.exp(-t / tm)
    return _divided(t, t1, t2)[1]


def ramp_response(t: float, time_constant: float, filter_time_constant: float | None = None) -> float:
    """The detector's residual [s] at ``t`` [s] on a unit ramp of external torque (1 Nm/s from 0), from rest:
    t - T_1 (1 - e^{-t/T_1}) for the observer alone, else the cascade's (module docstring)."""
    t1, t2 = time_constant, filter_time_constant
    if t2 is None:
        return t + t1 * math.expm1(-t / t1)
    return t - (t1 + t2) + _catch_up(t, t1, t2)


def detection_delay(
    zeta: float,
    step: float,
    time_constant: float,
    baseline: float = 0.0,
    filter_time_constant: float | None = None,
) -> float | None:
    """Time [s] for the residual b + s step(t) to reach ``zeta`` [Nm]; None if it never does (s <= zeta - b).

    ``baseline`` b [Nm], ``step`` s > 0 [Nm], ``time_constant`` T_o [s] of the observer and
    ``filter_time_constant`` T_f [s] of the residual's second stage (None: none; then the closed form
    t_d = -T_o ln(1 - (zeta - b) / s), else the root of the cascade's step response)."""
    _check_time_constants(time_constant, filter_time_constant)
    need = zeta - baseline
    if need <= 0.0:
        return 0.0
    if step <= need or need / step >= 1.0:  # (the step is zeta - b to round-off)
        return None
    if filter_time_constant is None:
        return float(-time_constant * math.log1p(-need / step))
    from scipy.optimize import brentq

    share, scale = need / step, time_constant + filter_time_constant
    hi = scale
    while step_response(hi, time_constant, filter_time_constant) <= share:  # 1 - step(t) decays: found at last
        hi *= 2.0

    def f(t: float) -> float:
        return step_response(t, time_constant, filter_time_constant) - share

    return float(brentq(f, 0.0, hi, xtol=ROOT_XTOL * scale))


def force_step_delays(
    robot: RobotModel,
    q: npt.ArrayLike,
    force: float,
    zeta: npt.ArrayLike,
    time_constant: float,
    filter_time_constant: float | None = None,
) -> list[dict[str, object]]:
    """Per direction of :data:`FORCE_DIRECTIONS`: the joint torques of a force step of ``force`` [N] at the
    end effector in posture ``q`` [rad], the first joint to cross its ``zeta`` (1-based) and the delay [s]
    (None: no joint's torque exceeds its zeta), through the observer of ``time_constant`` [s] and the second
    stage of ``filter_time_constant`` [s] (None: none)."""
    Jv = robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)[:3]
    z = np.broadcast_to(np.asarray(zeta, dtype=float), (robot.n,))
    rows: list[dict[str, object]] = []
    for name, u in FORCE_DIRECTIONS.items():
        tau = Jv.T @ (force * np.asarray(u))
        delays = [
            detection_delay(float(z[j]), abs(float(tau[j])), time_constant, filter_time_constant=filter_time_constant)
            for j in range(robot.n)
        ]
        found = [(d, j) for j, d in enumerate(delays) if d is not None]
        first = min(found) if found else None
        rows.append(
            {
                "direction": name,
                "joint_torque_Nm": [float(v) for v in tau],
                "first_joint": None if first is None else first[1] + 1,
                "delay_s": None if first is None else first[0],
            }
        )
    return rows


def ramp_lag(zeta: float, slope: float, time_constant: float, filter_time_constant: float | None = None) -> float:
    """The detector's own lag [s] on a ramp of external torque: tau(t) = ``slope`` t [Nm/s] from 0 crosses
    ``zeta`` [Nm] at t_0 = zeta / slope, the residual slope ramp(t) (module docstring) crosses it at t_d, and the
    lag is t_d - t_0.

    With the observer alone (``filter_time_constant`` None) r(t) = slope (t - T (1 - e^{-t/T})) of (8) and the
    lag is T (1 + W_0(-e^{-(1 + t_0 / T)})) (W_0: the principal branch of Lambert's W); with the second stage of
    time constant T_f the root of the cascade's ramp response. It rises with t_0 towards the sum of the time
    constants T + T_f (a slow ramp: the residual trails the torque by that much), which bounds the lag of any
    ramp; a step (t_0 -> 0) is :func:`detection_delay`.
    """
    from scipy.special import lambertw

    if not (zeta > 0 and slope > 0 and time_constant > 0):
        raise ConfigError(
            f"ramp_lag needs zeta, slope and time_constant > 0; got {zeta!r}, {slope!r}, {time_constant!r}"
        )
    _check_time_constants(time_constant, filter_time_constant)
    t0 = zeta / slope
    if filter_time_constant is not None:
        from scipy.optimize import brentq

        t1, t2, scale = time_constant, filter_time_constant, time_constant + filter_time_constant

        def behind(lag: float) -> float:  # ramp(t0 + lag) - t0, without subtracting t0 (a slow ramp's t0 >> scale)
            return lag - scale + _catch_up(t0 + lag, t1, t2)

        # ramp(t) lies in [t - scale, t]: the lag lies in [0, scale] (scale: the catch-up term underflowed)
        if behind(0.0) >= 0.0:  # t0 so small that the cascade's ramp(t0) ~ t0^3 / (6 T T_f) is t0 to round-off
            return 0.0
        return float(brentq(behind, 0.0, scale, xtol=ROOT_XTOL * scale))
    x = t0 / time_constant
    # W_0 near its branch point -1/e is ill-conditioned for tiny x; the series lag ~ sqrt(2 x) T - x T holds there
    if x < 1e-6:
        return float(time_constant * (math.sqrt(2.0 * x) - x))
    return float(time_constant * (1.0 + lambertw(-math.exp(-(1.0 + x)), 0).real))
