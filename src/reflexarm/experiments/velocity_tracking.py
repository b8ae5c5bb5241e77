"""Fig. 5: velocity tracking in a constant-velocity single-joint experiment, PD position control against
the impedance controller (2), both on the simulated Atlas arm with dry joint friction (Table I).

Sec. II-D.2 of the paper runs constant-velocity experiments joint by joint to identify friction and
reports (Fig. 5, joint 4 = elx) that the impedance controller tracks the commanded velocity better than
the manufacturer's "extensively tuned" PD position controller. Here joint ``joint`` (default elx) follows
a trapezoidal velocity profile (ramp, constant speed, ramp, and back) while the other joints hold; the
plant is the true arm with Table I friction as MuJoCo ``frictionloss``/``damping`` (stiction included)
and the paper's sensor noise; both controllers run on the same controller model (default +-10 % errors).

The two controllers:

* **PD position control** (:class:`JointPDController`): ``tau = K_p (q_d - q) + K_d (dq_d - dq) + g_hat(q)``
  per joint with gravity feed-forward from the model. The paper takes the manufacturer's gains from [5],
  [6], which are not given in it; the defaults here are a stiff, well-damped joint servo:
  ``K_p = 1000 Nm/rad`` and ``K_d = 30 Nms/rad`` on the hydraulic joints (elx, with ~0.32 kg m^2 about
  its axis: natural frequency ~56 rad/s, damping ratio ~0.8) and ``K_p = 100``, ``K_d = 3`` on the wrist.
* **Impedance control (2)** (:class:`reflexarm.control.Controller`): k_i = 300 Nm/rad, d_xi = 0.7 (the
  collision experiments' "Stiff" gains), kappa_f = kappa_eps = 0, no detection: the paper's settings.

Measured (seed 0, +-10 % model errors, 0.3 rad/s): RMS velocity error at constant speed PD 0.0072 rad/s,
impedance 0.0043 rad/s (the paper's ranking); over the whole run PD 0.016, impedance 0.038 rad/s. The
ranking follows the gains, not the structure of (2): the PD's K_d passes more velocity noise; with
K_d = 10 Nms/rad, or with the impedance's own gains (K_p = 300, K_d = 14), the PD tracks as well.

On another arm (:meth:`VelocityTrackingSetup.for_robot`) the experiment starts from the arm's start posture
(:func:`~reflexarm.experiments.any_arm.start_posture`), moves joint ceil(n/2) by default, at most at half its
velocity limit and inside its range, and the PD gains give every joint the bandwidth of Atlas' elx servo
(:data:`PD_BANDWIDTH`, :data:`PD_DAMPING_RATIO` on the joint's own inertia M_jj at the start posture).

The metric is the RMS of ``dq - dq_d`` of the moving joint (true velocity, not the noisy measurement)
over the constant-speed phases, after a settling margin; the RMS over the whole run (breakaway from
stiction and ramps included) is reported beside it, because the two controllers differ there most: the
stiffer PD breaks away from stiction sooner, the impedance controller rides more smoothly.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.control import Controller
from reflexarm.control.law_stability import experiment_stiffness
from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import RANGE_MARGIN, VELOCITY_SHARE, is_paper_arm, start_posture
from reflexarm.experiments.collision import controller_model
from reflexarm.experiments.link_push import default_link
from reflexarm.robots import RobotModel, load_robot
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise, Trace, run_closed_loop

__all__ = [
    "JointPDController",
    "TrapezoidalJointMotion",
    "VelocityTrackingResult",
    "VelocityTrackingSetup",
    "plot_velocity_tracking",
    "run_velocity_tracking",
]

ROBOT = "atlas_v5_left_arm"
#: Posture the experiment starts from (model order, [rad]): upper arm down and forward, elbow bent.
POSTURE = (0.0, -1.3, 1.57, 1.0, 0.0, 0.0, 0.0)
#: PD gains per joint, [Nm/rad] and [Nms/rad] (see the module docstring).
PD_KP = (1000.0, 1000.0, 1000.0, 1000.0, 100.0, 100.0, 100.0)
PD_KD = (30.0, 30.0, 30.0, 30.0, 3.0, 3.0, 3.0)
#: PD bandwidth on other arms [rad/s]: Atlas' elx servo, K_p = 1000 Nm/rad on ~0.32 kg m^2, is ~56 rad/s ...
PD_BANDWIDTH = 56.0
#: ... with damping ratio ~0.8 (K_d = 30 Nms/rad).
PD_DAMPING_RATIO = 0.8


class TrapezoidalJointMotion:
    """One joint moves ``travel`` at constant ``speed`` and back (trapezoidal velocity), the others hold.

    Timeline: hold ``hold`` s; accelerate for ``ramp`` s to ``+speed``; constant speed; decelerate; hold;
    then the same backwards; hold. The constant-speed phase lasts ``travel / speed - ramp`` s each way.

    Args:
        q0: start posture (n,) [rad].
        joint: moving joint (0-based).
        speed: constant speed [rad/s], > 0.
        travel: distance of each leg [rad], > speed * ramp.
        ramp: acceleration time [s], > 0.
        hold: rest before, between and after the legs [s].
    """

    def __init__(
        self, q0: npt.ArrayLike, joint: int, speed: float, travel: float, ramp: float = 0.2, hold: float = 0.5
    ) -> None:
        self.q0 = np.asarray(q0, dtype=float).copy()
        if not 0 <= joint < self.q0.size:
            raise ConfigError(f"joint must be in 0..{self.q0.size - 1}; got {joint}")
        for name, v in (("speed", speed), ("travel", travel), ("ramp", ramp)):
            if not (math.isfinite(v) and v > 0.0):
                raise ConfigError(f"{name} must be a positive number; got {v!r}")
        if not (math.isfinite(hold) and hold >= 0.0):
            raise ConfigError(f"hold must be a non-negative number of seconds; got {hold!r}")
        if travel <= speed * ramp:
            raise ConfigError(
                f"travel must exceed speed * ramp = {speed * ramp:g} rad (else no constant-speed phase); got {travel:g}"
            )
        self.joint, self.speed, self.travel, self.ramp, self.hold = int(joint), float(speed), float(travel), ramp, hold
        self.leg = travel / speed + ramp  # duration of one leg [s]
        self.duration = 3.0 * hold + 2.0 * self.leg

    def _leg(self, s: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) along one leg, s in [0, leg]."""
        v, r, a = self.speed, self.ramp, self.speed / self.ramp
        if s <= 0.0:
            return 0.0, 0.0, 0.0
        if s < r:
            return 0.5 * a * s * s, a * s, a
        if s <= self.leg - r:
            return 0.5 * v * r + v * (s - r), v, 0.0
        if s < self.leg:
            u = self.leg - s
            return self.travel - 0.5 * a * u * u, a * u, -a
        return self.travel, 0.0, 0.0

    def sample(self, t: float) -> Reference:
        """The reference at time t [s]."""
        s1 = t - self.hold
        s2 = t - (2.0 * self.hold + self.leg)
        if s2 > 0.0:
            p, v, a = self._leg(s2)
            p, v, a = self.travel - p, -v, -a
        else:
            p, v, a = self._leg(s1)
        q, dq, ddq = self.q0.copy(), np.zeros_like(self.q0), np.zeros_like(self.q0)
        q[self.joint] += p
        dq[self.joint] = v
        ddq[self.joint] = a
        return Reference(q, dq, ddq)

    def constant_speed(self, t: np.ndarray, margin: float) -> np.ndarray:
        """Mask of times in the constant-speed phases, ``margin`` s after each phase starts."""
        t = np.asarray(t, dtype=float)
        mask = np.zeros(t.shape, dtype=bool)
        for start in (self.hold, 2.0 * self.hold + self.leg):
            mask |= (t >= start + self.ramp + margin) & (t <= start + self.leg - self.ramp)
        return mask

    def describe(self) -> dict[str, object]:
        return {
            "type": "TrapezoidalJointMotion",
            "joint": self.joint,
            "speed": self.speed,
            "travel": self.travel,
            "ramp": self.ramp,
            "hold": self.hold,
        }


class JointPDController:
    """Joint PD position control with gravity feed-forward: ``tau = K_p e + K_d de + g_hat(q)``.

    Args:
        robot: the controller's model (for g_hat and the torque limits).
        kp: K_p per joint (n,) or scalar [Nm/rad], positive.
        kd: K_d per joint (n,) or scalar [Nms/rad], non-negative.
    """

    def __init__(self, robot: RobotModel, kp: npt.ArrayLike, kd: npt.ArrayLike) -> None:
        self.robot = robot
        n = robot.n
        self.kp = np.broadcast_to(np.asarray(kp, dtype=float), (n,)).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(self.kp)) or np.any(self.kp <= 0.0):
            raise ConfigError(f"kp must be positive [Nm/rad]; got {self.kp.tolist()}")
        if not np.all(np.isfinite(self.kd)) or np.any(self.kd < 0.0):
            raise ConfigError(f"kd must be non-negative [Nms/rad]; got {self.kd.tolist()}")
        self._limit = np.asarray(robot.effort_limit, dtype=float)
        self._zeros = np.zeros(n)

    def reset(self) -> None:
        """Stateless; nothing to clear."""

    def step(self, measurement: Measurement, reference: Reference) -> Command:
        """The PD torque for one tick (clipped to the model's effort limits)."""
        q, dq = measurement.q, measurement.dq
        tau = self.kp * (reference.q_d - q) + self.kd * (reference.dq_d - dq) + self.robot.compute_gravity(q)
        tau = np.clip(tau, -self._limit, self._limit)
        return Command(tau, self._zeros, False, (), "pd_position", "")

    def describe(self) -> dict[str, object]:
        return {"type": "JointPDController", "kp": self.kp.tolist(), "kd": self.kd.tolist()}


@dataclass(frozen=True)
class VelocityTrackingSetup:
    """The experiment of Fig. 5 (see the module docstring); speeds [rad/s], angles [rad], gains SI."""

    joint: int = 3
    speed: float = 0.3
    travel: float = 0.9
    ramp: float = 0.2
    hold: float = 0.5
    posture: tuple[float, ...] = POSTURE
    pd_kp: tuple[float, ...] = PD_KP
    pd_kd: tuple[float, ...] = PD_KD
    stiffness: float = 300.0
    damping_ratio: float = 0.7
    #: settling margin after each acceleration ramp before the RMS window opens [s]
    settle: float = 0.3

    def motion(self) -> TrapezoidalJointMotion:
        return TrapezoidalJointMotion(self.posture, self.joint, self.speed, self.travel, self.ramp, self.hold)

    @classmethod
    def for_robot(cls, robot: RobotModel, joint: int | None = None) -> VelocityTrackingSetup:
        """The setup on ``robot``: the paper's on Atlas; elsewhere derived (module docstring). ``joint``
        is 0-based (default: Atlas' elx, else joint ceil(n/2)).

        Raises:
            ConfigError: ``joint`` outside 0..n-1.
        """
        if joint is not None and not 0 <= joint < robot.n:
            raise ConfigError(f"joint must be in 1..{robot.n} (1-based); got {joint + 1}")
        if is_paper_arm(robot):
            return cls() if joint is None else cls(joint=joint)
        j = default_link(robot) - 1 if joint is None else joint
        q0 = start_posture(robot)
        lo, hi = robot.lower_limit[j], robot.upper_limit[j]
        bounded = bool(np.isfinite(lo) and np.isfinite(hi) and hi > lo)
        room = (1.0 - 2.0 * RANGE_MARGIN) * (hi - lo) if bounded else math.inf
        travel = float(min(0.9, room))
        vlim = float(robot.velocity_limit[j])
        speed = min(0.3, VELOCITY_SHARE * vlim) if math.isfinite(vlim) and vlim > 0 else 0.3
        speed = min(speed, 0.5 * travel / 0.2)  # a constant-speed phase after the 0.2 s ramp
        if bounded:
            q0[j] = float(np.clip(q0[j], lo + RANGE_MARGIN * (hi - lo), hi - RANGE_MARGIN * (hi - lo) - travel))
        inertia = np.maximum(np.diag(robot.compute_mass_matrix(q0)), 1e-3)
        kp = tuple(float(x) for x in inertia * PD_BANDWIDTH**2)
        kd = tuple(float(x) for x in 2.0 * PD_DAMPING_RATIO * PD_BANDWIDTH * inertia)
        return cls(joint=j, speed=speed, travel=travel, posture=tuple(float(x) for x in q0), pd_kp=kp, pd_kd=kd)


@dataclass
class VelocityTrackingResult:
    """The two runs, keyed "PD" and "impedance", and their velocity errors on the moving joint [rad/s]:
    RMS and max over the constant-speed windows, and RMS over the whole run (ramps and breakaway
    from stiction included)."""

    setup: VelocityTrackingSetup
    traces: dict[str, Trace]
    rms_velocity_error: dict[str, float]
    max_velocity_error: dict[str, float]
    rms_velocity_error_all: dict[str, float]
    model_info: dict[str, object] = field(default_factory=dict)

    def rows(self) -> list[dict[str, Any]]:
        """One table row per controller."""
        return [
            {
                "controller": name,
                "rms_dq_error": self.rms_velocity_error[name],
                "max_dq_error": self.max_velocity_error[name],
                "rms_dq_error_all": self.rms_velocity_error_all[name],
                "speed": self.setup.speed,
            }
            for name in self.traces
        ]

    def as_dict(self) -> dict[str, Any]:
        return {"setup": asdict(self.setup), "controller_model": self.model_info, "rows": self.rows()}


def run_velocity_tracking(
    setup: VelocityTrackingSetup | None = None,
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    model: RobotModel | None = None,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
    robot: RobotModel | None = None,
) -> VelocityTrackingResult:
    """Run the PD and the impedance controller on the same motion, plant, noise and controller model
    (on ``robot``, default the built-in Atlas arm; :meth:`VelocityTrackingSetup.for_robot` its setup).

    Raises:
        ConfigError: the setup's posture or gains do not have the robot's number of joints.
    """
    robot = load_robot(ROBOT) if robot is None else robot
    setup = setup or VelocityTrackingSetup.for_robot(robot)
    for name in ("posture", "pd_kp", "pd_kd"):
        if len(getattr(setup, name)) != robot.n:
            raise ConfigError(
                f"setup.{name} has {len(getattr(setup, name))} values; {robot.name!r} has {robot.n} joints "
                "(use VelocityTrackingSetup.for_robot)"
            )
    ctrl_model, info = controller_model(robot, model_error, model_seed, model)
    motion = setup.motion()
    controllers: dict[str, Any] = {
        "PD": JointPDController(ctrl_model, setup.pd_kp, setup.pd_kd),
        "impedance": Controller(
            ctrl_model,
            stiffness=experiment_stiffness(ctrl_model, setup.stiffness, setup.damping_ratio),
            damping_ratio=setup.damping_ratio,
            threshold=None,
            reaction="none",
        ),
    }
    traces: dict[str, Trace] = {}
    rms: dict[str, float] = {}
    peak: dict[str, float] = {}
    rms_all: dict[str, float] = {}
    for name, ctrl in controllers.items():
        plant = Plant(robot, noise=noise, seed=seed)
        plant.reset(np.asarray(setup.posture, dtype=float))
        tr = run_closed_loop(plant, ctrl, motion, motion.duration, progress=progress)
        tr.meta.update(
            {"experiment": "velocity_tracking", "robot": robot.name, "controller_name": name, "controller_model": info}
        )
        err = tr.dq[:, setup.joint] - tr.dq_d[:, setup.joint]
        window = motion.constant_speed(tr.t, setup.settle)
        traces[name] = tr
        rms[name] = float(np.sqrt(np.mean(err[window] ** 2)))
        peak[name] = float(np.abs(err[window]).max())
        rms_all[name] = float(np.sqrt(np.mean(err**2)))
    return VelocityTrackingResult(setup, traces, rms, peak, rms_all, info)


def plot_velocity_tracking(result: VelocityTrackingResult, path: str | Path) -> Path:
    """Desired and actual velocity of the moving joint for both controllers, and the velocity error (Fig. 5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    j = result.setup.joint
    fig, axes = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    first = next(iter(result.traces.values()))
    axes[0].plot(first.t, first.dq_d[:, j], "k--", lw=1, label=f"dq_d,{j + 1}")
    colors = {"PD": "tab:orange", "impedance": "tab:blue"}
    for name, tr in result.traces.items():
        c = colors.get(name)
        rms = result.rms_velocity_error[name]
        axes[0].plot(tr.t, tr.dq[:, j], color=c, lw=1, label=f"{name} (RMS error {rms:.3f} rad/s)")
        axes[1].plot(tr.t, tr.dq[:, j] - tr.dq_d[:, j], color=c, lw=1, label=name)
    axes[0].set_ylabel(f"dq_{j + 1} [rad/s]")
    axes[1].set_ylabel(f"dq_{j + 1} - dq_d,{j + 1} [rad/s]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title(f"Constant-velocity run of joint {j + 1}: PD vs impedance control (cf. Fig. 5)")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
