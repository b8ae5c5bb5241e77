"""Logging identification runs on the simulated plant, and closing the loop with an identified model.

* :func:`simulate_log`: run a trajectory on the MuJoCo plant with the joint impedance controller and
  record what a real robot would log (noisy q, dq, tau_m) as a :class:`~reflexarm.ident.RobotLog`.
* :func:`compare_tracking`: the controller with different models (e.g. identified against perturbed
  nominal), on the same trajectory and plant.

Two plants are offered (``scenario``):

* ``"table1"``: the plant's friction is exactly the model's form (Coulomb + viscous, Table I values).
* ``"stribeck"``: the same plus a Stribeck/stiction term the model does not have, :class:`StribeckFriction`:
  ``tau_s(dq) = -(r - 1) mu_C exp(-(dq / v_s)^2) tanh(dq / eps)`` with static-to-Coulomb ratio r = 1.5,
  Stribeck velocity v_s = 0.1 rad/s and eps = 5e-3 rad/s (a smooth sign, so the integrator does not
  chatter at rest): at rest the breakaway torque is 1.5 mu_C, decaying to mu_C above ~0.2 rad/s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.control import Controller
from reflexarm.control.law_stability import experiment_stiffness
from reflexarm.errors import ConfigError
from reflexarm.ident import RobotLog
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Command, Measurement
from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise, run_closed_loop
from reflexarm.sim.trace import Trace

__all__ = [
    "HYDRAULIC_JOINTS",
    "IDENT_STIFFNESS",
    "MOVING_SPEED",
    "NOMINAL_ERROR_LEVEL",
    "SCENARIOS",
    "StribeckFriction",
    "TrackingComparison",
    "compare_tracking",
    "hydraulic_joints",
    "scenario_extra",
    "simulate_log",
]

#: The hydraulic joints of the Atlas arm (shz, shx, ely, elx), 0-based.
HYDRAULIC_JOINTS = (0, 1, 2, 3)
#: Names (suffixes) of the Atlas arm's hydraulic joints, left or right arm.
_HYDRAULIC_SUFFIXES = ("_arm_shz", "_arm_shx", "_arm_ely", "_arm_elx")
#: Plant friction scenarios of :func:`run_identification_study`.
SCENARIOS = ("table1", "stribeck")
#: Stiffness of the impedance controller during identification runs [Nm/rad] (the paper's "stiff").
IDENT_STIFFNESS = 300.0
#: Model-error level of the "perturbed nominal" model (the paper's +-10 %).
NOMINAL_ERROR_LEVEL = 0.1
#: Speed below which a joint counts as not moving [rad/s]: the paper's velocity noise level, below
#: which the sign of the measured velocity (hence of the Coulomb torque) is undetermined.
MOVING_SPEED = PAPER_NOISE.dq


@dataclass(frozen=True)
class StribeckFriction:
    """Extra plant torque: a Stribeck/stiction term on top of Coulomb friction (see the module docstring).

    Attributes:
        coulomb: mu_C per joint [Nm] (the plant's Coulomb level the term scales with).
        static_ratio: r = mu_S / mu_C.
        stribeck_velocity: v_s [rad/s].
        smoothing: eps of the smooth sign [rad/s].
    """

    coulomb: np.ndarray
    static_ratio: float = 1.5
    stribeck_velocity: float = 0.1
    smoothing: float = 5e-3

    def __call__(self, q: np.ndarray, dq: np.ndarray, t: float) -> np.ndarray:
        """Passive joint torque added to the motor torque [Nm] (opposes the motion)."""
        return (
            -(self.static_ratio - 1.0)
            * self.coulomb
            * np.exp(-((dq / self.stribeck_velocity) ** 2))
            * np.tanh(dq / self.smoothing)
        )

    def describe(self) -> dict[str, object]:
        return {
            "law": "-(r - 1) mu_C exp(-(dq/v_s)^2) tanh(dq/eps)",
            "static_ratio": self.static_ratio,
            "stribeck_velocity": self.stribeck_velocity,
            "smoothing": self.smoothing,
            "coulomb": self.coulomb.tolist(),
        }


def hydraulic_joints(robot: RobotModel) -> tuple[int, ...]:
    """0-based indices of the Atlas arm's hydraulic joints in ``robot`` (by joint name); () on other arms.

    The paper reports Table I's difference on these joints; on any other arm the study compares all joints.
    """
    return tuple(j for j, name in enumerate(robot.joint_names) if name.endswith(_HYDRAULIC_SUFFIXES))


def scenario_extra(robot: RobotModel, scenario: str) -> StribeckFriction | None:
    """The extra plant torque of ``scenario`` (None for ``"table1"``)."""
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    return StribeckFriction(robot.friction.coulomb.copy()) if scenario == "stribeck" else None


# ---------------------------------------------------------------------------------------------- one run
def simulate_log(
    robot: RobotModel,
    trajectory: Any,
    duration: float,
    *,
    controller_model: RobotModel | None = None,
    stiffness: npt.ArrayLike = IDENT_STIFFNESS,
    kappa_f: int = 0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    true_friction: CoulombViscousFriction | None = None,
    extra_joint_torque: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
    source: str = "simulation",
    progress: bool = False,
) -> tuple[RobotLog, Trace]:
    """Run ``trajectory`` on the plant of ``robot`` with the impedance controller; log what a robot reports.

    The log row k holds the measured q, dq at tick k and the measured motor torque of the command
    sent at tick k (the plant reports a command's torque one tick later; the row pairs it with the
    state it started acting on). The last tick has no such torque and is dropped.

    Args:
        robot: the true arm (plant).
        trajectory: anything with ``sample(t)`` and a start pose ``start`` (else q(0) of ``sample(0)``).
        duration: simulated time [s].
        controller_model: the controller's model (default: ``robot`` itself).
        stiffness: K [Nm/rad]; kappa_f: friction compensation in (2).
        noise, seed: sensor noise levels and seed.
        true_friction, extra_joint_torque: see :class:`reflexarm.sim.Plant`.
        source: name of the log.
        progress: progress bar.
    """
    plant = Plant(robot, noise=noise, seed=seed, true_friction=true_friction, extra_joint_torque=extra_joint_torque)
    start = getattr(trajectory, "start", None)
    q0 = np.asarray(start if start is not None else trajectory.sample(0.0).q_d, dtype=float)
    plant.reset(q0)
    model = controller_model if controller_model is not None else robot
    ctrl = Controller(
        model,
        stiffness=experiment_stiffness(model, np.asarray(stiffness, dtype=float)),
        damping_ratio=0.7,
        observer_gain=5.0,
        threshold=None,
        reaction="none",
        kappa_f=kappa_f,
        kappa_eps=0,
        kappa_ext=0,
        dt=plant.control_period,
    )
    steps = int(round(duration / plant.control_period))
    t = np.empty(steps)
    q = np.empty((steps, robot.n))
    dq = np.empty((steps, robot.n))
    tau = np.empty((steps, robot.n))
    wrench = np.empty((steps, 6))

    def record(k: int, _plant: Plant, m: Measurement, _cmd: Command) -> None:
        if k < steps:
            t[k] = m.t
            q[k] = m.q
            dq[k] = m.dq
            tau[k] = m.tau_m
            wrench[k] = m.wrench

    trace = run_closed_loop(plant, ctrl, trajectory, duration, callback=record, progress=progress)
    k = trace.t.size
    log = RobotLog(
        t=t[: k - 1],
        q=q[: k - 1],
        dq=dq[: k - 1],
        tau=tau[1:k],
        source=source,
        notes=(
            f"simulated on the MuJoCo plant of {robot.name!r} with the impedance controller (K = "
            f"{np.atleast_1d(stiffness).tolist()} Nm/rad), noise {noise.as_dict()}, seed {seed}",
        ),
    )
    return log, trace


# ---------------------------------------------------------------------------------------------- closing the loop
@dataclass(frozen=True)
class TrackingComparison:
    """Tracking of the same trajectory on the same plant with different controller models.

    Attributes:
        rms_error: per model name, RMS of q_d - q per joint [rad].
        max_error: per model name, max |q_d - q| per joint [rad].
        traces: the runs.
    """

    rms_error: dict[str, np.ndarray]
    max_error: dict[str, np.ndarray]
    traces: dict[str, Trace]

    def table(self, joint_names: Sequence[str]) -> list[dict[str, object]]:
        rows = []
        for name in self.rms_error:
            row: dict[str, object] = {"model": name}
            for j in range(len(joint_names)):
                row[f"rms_{j + 1}"] = float(self.rms_error[name][j])
            row["rms_all"] = float(np.sqrt(np.mean(self.rms_error[name] ** 2)))
            rows.append(row)
        return rows


def compare_tracking(
    robot: RobotModel,
    models: dict[str, RobotModel],
    trajectory: Any,
    duration: float,
    *,
    kappa_f: int = 1,
    stiffness: npt.ArrayLike = IDENT_STIFFNESS,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    extra_joint_torque: Any = None,
    settle: float = 0.5,
    progress: bool = False,
) -> TrackingComparison:
    """Run ``trajectory`` on the plant of ``robot`` with each controller model; position tracking errors.

    Args:
        robot: the true arm.
        models: controller models by name (e.g. ``{"nominal": perturbed, "identified": identified}``).
        trajectory, duration: the reference and run length [s].
        kappa_f: friction compensation in (2) with each model's friction (1: the identified friction is
            used, as the paper intends).
        stiffness, noise, seed, extra_joint_torque: run settings (identical for every model).
        settle: initial seconds excluded from the error statistics [s].
    """
    rms, mx, traces = {}, {}, {}
    for name, model in models.items():
        _, tr = simulate_log(
            robot,
            trajectory,
            duration,
            controller_model=model,
            stiffness=stiffness,
            kappa_f=kappa_f,
            noise=noise,
            seed=seed,
            extra_joint_torque=extra_joint_torque,
            source=name,
            progress=progress,
        )
        m = tr.t >= settle
        e = tr.q_d[m] - tr.q[m]
        rms[name] = np.sqrt(np.mean(e**2, axis=0))
        mx[name] = np.max(np.abs(e), axis=0)
        traces[name] = tr
    return TrackingComparison(rms, mx, traces)
