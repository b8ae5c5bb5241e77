"""Detection delays implied by a threshold: a torque step at a joint, or a force step at the end effector.

The observer's residual follows an external torque step s with the first-order response (8),
r(t) = b + s (1 - exp(-t / T_o)), T_o = -dt / ln(1 - k_o dt) (the discrete observer's time constant,
1/k_o to 0.3 % for k_o dt <= 0.005), b the residual before the step. It reaches zeta at

    t_d = -T_o ln(1 - (zeta - b) / s)      (never if s <= zeta - b; 0 if b >= zeta).

A force F at the end effector reaches the joints as tau = J_v(q)^T F (J_v: the linear rows of the
end-effector Jacobian, world-aligned); the arm detects it at the first joint whose |tau_j| crosses.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

__all__ = ["FORCE_DIRECTIONS", "detection_delay", "force_step_delays", "ramp_lag"]

#: The directions of the end-effector force step: the base frame's axes, both signs.
FORCE_DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


def detection_delay(zeta: float, step: float, time_constant: float, baseline: float = 0.0) -> float | None:
    """Time [s] for r = b + s (1 - exp(-t / T_o)) to reach ``zeta``; None if it never does (s <= zeta - b).
    ``baseline`` b [Nm], ``time_constant`` T_o [s], ``step`` s > 0 [Nm]."""
    need = zeta - baseline
    if need <= 0.0:
        return 0.0
    if step <= need:
        return None
    return float(-time_constant * math.log1p(-need / step))


def force_step_delays(
    robot: RobotModel, q: npt.ArrayLike, force: float, zeta: npt.ArrayLike, time_constant: float
) -> list[dict[str, object]]:
    """Per direction of :data:`FORCE_DIRECTIONS`: the joint torques of a force step of ``force`` [N] at the
    end effector in posture ``q`` [rad], the first joint to cross its ``zeta`` (1-based) and the delay [s]
    (None: no joint's torque exceeds its zeta)."""
    Jv = robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)[:3]
    z = np.broadcast_to(np.asarray(zeta, dtype=float), (robot.n,))
    rows: list[dict[str, object]] = []
    for name, u in FORCE_DIRECTIONS.items():
        tau = Jv.T @ (force * np.asarray(u))
        delays = [detection_delay(float(z[j]), abs(float(tau[j])), time_constant) for j in range(robot.n)]
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


def ramp_lag(zeta: float, slope: float, time_constant: float) -> float:
    """The detector's own lag [s] on a ramp of external torque: tau(t) = ``slope`` t [Nm/s] from 0 crosses
    ``zeta`` [Nm] at t_0 = zeta / slope; the first-order residual r(t) = slope (t - T (1 - e^{-t/T})) of (8)
    crosses it at t_d, and the lag is t_d - t_0 = T (1 + W_0(-e^{-(1 + t_0 / T)})) (W_0: the principal
    branch of Lambert's W). It rises with t_0 / T towards T = ``time_constant`` (a slow ramp: the residual
    trails the torque by T), so T bounds the lag of any ramp; a step (t_0 -> 0) is :func:`detection_delay`.
    """
    from scipy.special import lambertw

    if not (zeta > 0 and slope > 0 and time_constant > 0):
        raise ConfigError(
            f"ramp_lag needs zeta, slope and time_constant > 0; got {zeta!r}, {slope!r}, {time_constant!r}"
        )
    x = zeta / slope / time_constant
    # W_0 near its branch point -1/e is ill-conditioned for tiny x; the series lag ~ sqrt(2 x) T - x T holds there
    if x < 1e-6:
        return float(time_constant * (math.sqrt(2.0 * x) - x))
    return float(time_constant * (1.0 + lambertw(-math.exp(-(1.0 + x)), 0).real))
