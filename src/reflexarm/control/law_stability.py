"""Whether the joint impedance law (2) is stable at the control rate: its modes sampled with a zero-order hold.

The law's stiffness K and modal damping (double diagonalization of M(q) and K) decouple the arm into modes
z_i'' = -omega_i^2 z_i - 2 d_xi_i omega_i z_i' (omega_i^2 the eigenvalues of K v = omega^2 M(q) v). A controller
that computes the torque from the state at a tick and holds it for the period dt turns each mode into the map
(z, z' dt) -> Phi(x) (z, z' dt), x = omega dt:

    Phi = [[1 - x^2/2, 1 - d_xi x], [-x^2, 1 - 2 d_xi x]],  tr = 2 - x^2/2 - 2 d_xi x,  det = 1 - 2 d_xi x + x^2/2.

By the Jury conditions it is stable for x < min(1/d_xi, 4 d_xi) (d_xi > 0): beyond 1/d_xi an eigenvalue passes -1
(the mode flips sign every tick and grows), beyond 4 d_xi the pair leaves the unit circle (the hold's lag eats the
damping). The continuous law is stable at any stiffness; the sampled one is not: a light distal link (a vendor
URDF without the motors' reflected inertia, e.g. a UR5e wrist of 1.3e-4 kg m^2) at the paper's 300 Nm/rad has
omega = 1.5e3 rad/s, x = 1.5 at 1 kHz, above 1/0.7 = 1.43, and the wrist's speed doubles every tick from rest.

A simulator that integrates the period in semi-implicit Euler steps moves the position further under the held
torque and is stricter (:func:`limit_omega_dt`'s ``position_gain``; reflexarm's Plant: 1.18 at d_xi = 0.7, against
1.43 on a real arm); the Controller warns at the real arm's limit, and a plant that diverges says so
(SimulationError). :data:`RATE_SHARE` of the real arm's limit is within the Plant's for every damping ratio (at
most 0.95 of it, at d_xi = 0.5).

Only the law is examined (the observer, compensation and friction terms are not): a necessary condition, checked
on the controller's model at its home posture and at zero (clipped to the limits); the highest modes are those
of the distal joints, whose inertia changes little with the posture. A mode of ratio 0 (undamped) is not checked:
its continuous law is marginal already.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "LawMode",
    "UnstableLawWarning",
    "check_law_stability",
    "warn_if_unstable",
    "experiment_stiffness",
    "law_modes",
    "limit_omega_dt",
    "worst_mode",
    "rate_limited_stiffness",
    "unstable_law_message",
]

#: rate_limited_stiffness's target: each mode at most this share of its stability limit omega dt (0.7: a stiffness
#: below half the limit's; at 300 Nm/rad and 1 kHz the built-in arms' highest modes are at 0.19-0.52 of theirs,
#: the example UR-like arm's at 0.56, so they keep their stiffness).
RATE_SHARE = 0.7


def limit_omega_dt(damping_ratio: float, position_gain: float = 0.5) -> float:
    """The largest omega dt at which a mode with this modal damping ratio is stable when sampled with a hold
    (inf for a ratio <= 0: not checked, see the module docstring).

    ``position_gain`` c: the held acceleration a moves the position by c a dt^2 over the period: 1/2 on a real arm
    (continuous motion); (N + 1) / (2 N) on a simulator that integrates the period in N semi-implicit Euler steps
    (MuJoCo's default; reflexarm's Plant: N = 2, c = 3/4), which makes the limit stricter. With it
    Phi = [[1 - c x^2, 1 - 2 c d_xi x], [-x^2, 1 - 2 d_xi x]]: 1 + tr + det = 4 - 4 d_xi x + (1 - 2 c) x^2 > 0 and
    det = 1 - 2 d_xi x + (1 - c) x^2 < 1."""
    d, c = float(damping_ratio), float(position_gain)
    if d <= 0.0:
        return float("inf")
    a = 2.0 * c - 1.0
    flip = 1.0 / d if abs(a) < 1e-12 else 2.0 * (math.sqrt(d * d + a) - d) / a
    lag = 2.0 * d / (1.0 - c) if c < 1.0 else float("inf")
    return min(flip, lag)


@dataclass(frozen=True)
class LawMode:
    """One mode of the law at a posture: omega [rad/s], omega dt, its limit, and the joint that carries most of
    its stiffness (k_j v_j^2 of the M-normalized mode shape v)."""

    omega: float
    omega_dt: float
    limit: float
    joint: int
    posture: str

    @property
    def share(self) -> float:
        """omega dt / its limit: >= 1 unstable."""
        return self.omega_dt / self.limit


def _postures(robot: RobotModel) -> list[tuple[str, np.ndarray]]:
    lo, hi = np.asarray(robot.lower_limit, dtype=float), np.asarray(robot.upper_limit, dtype=float)
    zero = np.clip(np.zeros(robot.n), lo, hi)
    home = np.clip(np.asarray(robot.home, dtype=float), lo, hi)
    out = [("home", home)]
    if not np.array_equal(zero, home):
        out.append(("zero", zero))
    return out


def law_modes(
    robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float, position_gain: float = 0.5
) -> list[LawMode]:
    """Every mode of the law at each checked posture (see the module docstring), ascending omega per posture
    (``position_gain``: see :func:`limit_omega_dt`)."""
    k = np.asarray(stiffness, dtype=float)
    d = np.asarray(damping_ratio, dtype=float)
    modes = []
    for name, q in _postures(robot):
        M = robot.compute_mass_matrix(q)
        w2, V = scipy.linalg.eigh(np.diag(k), M)  # ascending, V^T M V = I: the law's modal order
        for i in range(robot.n):
            omega = float(np.sqrt(max(w2[i], 0.0)))
            joint = int(np.argmax(k * V[:, i] ** 2))
            modes.append(LawMode(omega, omega * dt, limit_omega_dt(d[i], position_gain), joint, name))
    return modes


def worst_mode(robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float) -> LawMode:
    """The mode of :func:`law_modes` nearest its limit (largest share) over the checked postures."""
    return max(law_modes(robot, stiffness, damping_ratio, dt), key=lambda m: m.share)


def _lowered(robot: RobotModel, k: np.ndarray, capped: np.ndarray, lowered: list[int], sep: str = ", ") -> str:
    """"joint old -> new" for each joint lowered."""
    return sep.join(f"{robot.joint_names[j]} {k[j]:.4g} -> {capped[j]:.3g}" for j in lowered)


def unstable_law_message(robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float) -> str | None:
    """None if every mode of the law is stable at the period ``dt``, else what is unstable and what would do."""
    worst = worst_mode(robot, stiffness, damping_ratio, dt)
    if worst.share < 1.0:
        return None
    k = np.asarray(stiffness, dtype=float)
    capped, lowered = rate_limited_stiffness(robot, k, damping_ratio, dt)
    changes = _lowered(robot, k, capped, lowered, "; ")
    return (
        f"the impedance law is unstable at dt = {dt:g} s: its mode dominated by joint {worst.joint + 1} "
        f"({robot.joint_names[worst.joint]}) has omega = {worst.omega:.4g} rad/s at the {worst.posture} posture, "
        f"omega dt = {worst.omega_dt:.3g} >= {worst.limit:.3g} (the limit for its damping ratio; the held torque "
        f"flips sign and grows every tick). The link is too light for this stiffness at this rate (a robot file "
        f"without the motors' reflected inertia?): lower the stiffness [Nm/rad] ({changes} keeps every "
        f"mode within {RATE_SHARE:g} of its limit), or run faster"
    )


class UnstableLawWarning(UserWarning):
    """A controller's law is unstable at its rate (:func:`unstable_law_message`): harmless for a controller that
    only monitors (a log replay, a collision monitor: its torque is never applied), unsafe for one that drives."""


def warn_if_unstable(
    robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float, stacklevel: int = 3
) -> None:
    """An :class:`UnstableLawWarning` with :func:`unstable_law_message`'s text if a mode is unstable at ``dt``."""
    message = unstable_law_message(robot, stiffness, damping_ratio, dt)
    if message is not None:
        warnings.warn(
            f"{message} (a controller whose torque is applied must not run this law; one that only monitors, e.g. "
            "a log replay, may)",
            UnstableLawWarning,
            stacklevel=stacklevel,
        )


def check_law_stability(robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float) -> None:
    """Raises ConfigError (:func:`unstable_law_message`'s text) if a mode of the law is unstable at ``dt``."""
    message = unstable_law_message(robot, stiffness, damping_ratio, dt)
    if message is not None:
        raise ConfigError(message)


def rate_limited_stiffness(
    robot: RobotModel, stiffness: np.ndarray, damping_ratio: np.ndarray, dt: float, share: float = RATE_SHARE
) -> tuple[np.ndarray, list[int]]:
    """The stiffness with each joint lowered where needed so that every mode is within ``share`` of its limit
    (the joints lowered). A mode above it lowers the joint that carries most of its stiffness by the square of the
    excess (omega^2 is the mode's Rayleigh quotient, sum_j k_j v_j^2), until none is above (at most 100 steps)."""
    k = np.array(stiffness, dtype=float)
    d = np.asarray(damping_ratio, dtype=float)
    lowered: set[int] = set()
    for _ in range(100):
        worst = worst_mode(robot, k, d, dt)
        if worst.share <= share * (1.0 + 1e-9):
            break
        k[worst.joint] *= (share / worst.share) ** 2
        lowered.add(worst.joint)
    return k, sorted(lowered)


def experiment_stiffness(
    robot: RobotModel, stiffness: float | np.ndarray, damping_ratio: float | np.ndarray = 0.7, dt: float = 1e-3
) -> np.ndarray:
    """The stiffness an experiment runs the law with on ``robot``: its setting (the paper's, e.g. 300 Nm/rad) where
    the law is stable at ``dt``, else :func:`rate_limited_stiffness`'s, with a UserWarning naming each joint lowered
    (the paper's gains on a vendor file without the motors' reflected inertia would otherwise make the plant
    diverge, or the controller fault, a few ticks into every experiment on that arm)."""
    k = np.broadcast_to(np.asarray(stiffness, dtype=float), (robot.n,)).copy()
    d = np.broadcast_to(np.asarray(damping_ratio, dtype=float), (robot.n,))
    if worst_mode(robot, k, d, dt).share < 1.0:
        return k
    capped, lowered = rate_limited_stiffness(robot, k, d, dt)
    changes = _lowered(robot, k, capped, lowered)
    warnings.warn(
        f"{robot.name}: the law at the experiment's stiffness is unstable at dt = {dt:g} s (a link too light for it; "
        f"reflexarm.control.law_stability); stiffness lowered [Nm/rad]: {changes}",
        UserWarning,
        stacklevel=2,
    )
    return capped
