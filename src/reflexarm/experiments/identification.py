"""Identification experiments on the simulated plant, run with the impedance controller (Sec. II-D).

* :func:`simulate_log`: run a trajectory on the MuJoCo plant with the joint impedance controller and
  record what a real robot would log (noisy q, dq, tau_m) as a :class:`~reflexarm.ident.RobotLog`.
* :func:`run_friction_experiments`: the single-joint constant-velocity runs of Fig. 4/5 and the
  Coulomb + viscous fit per joint (Table I).
* :func:`run_identification_study`: friction runs, an optimized Fourier excitation run and a different
  validation run; base parameters by the combined (beta_I) and the sequential (beta_II) method; the
  Table I analogue of validation MSE per joint.
* :func:`compare_tracking`: closing the loop: the controller with the identified model against the
  perturbed nominal one, on the same trajectory and plant.

Two plants are offered (``scenario``):

* ``"table1"``: the plant's friction is exactly the model's form (Coulomb + viscous, Table I values).
* ``"stribeck"``: the same plus a Stribeck/stiction term the model does not have, :class:`StribeckFriction`:
  ``tau_s(dq) = -(r - 1) mu_C exp(-(dq / v_s)^2) tanh(dq / eps)`` with static-to-Coulomb ratio r = 1.5,
  Stribeck velocity v_s = 0.1 rad/s and eps = 5e-3 rad/s (a smooth sign, so the integrator does not
  chatter at rest): at rest the breakaway torque is 1.5 mu_C, decaying to mu_C above ~0.2 rad/s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.control import Controller
from reflexarm.errors import ConfigError
from reflexarm.ident.base_parameters import compute_base_parameters
from reflexarm.ident.estimation import (
    DynamicsIdentification,
    FrictionParameters,
    TorqueValidation,
    identify_dynamics,
    validate_model,
)
from reflexarm.ident.excitation import ExcitationDesign, FourierTrajectory, optimize_excitation
from reflexarm.ident.joint_friction import (
    DEFAULT_SETTLE_TIME,
    ConstantVelocityTrajectory,
    FrictionFit,
    friction_from_fits,
    identify_joint_friction,
    plan_friction_experiment,
)
from reflexarm.ident.logs import RobotLog, preprocess_log
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.perturbation import perturb_model
from reflexarm.robots.robot_model import RobotModel, load_robot
from reflexarm.signals import Command, Measurement
from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise, run_closed_loop
from reflexarm.sim.trace import Trace

__all__ = [
    "HYDRAULIC_JOINTS",
    "MOVING_SPEED",
    "SCENARIOS",
    "FrictionExperiment",
    "IdentificationStudy",
    "StribeckFriction",
    "TrackingComparison",
    "compare_tracking",
    "run_friction_experiments",
    "run_identification_study",
    "simulate_log",
]

#: The hydraulic joints of the Atlas arm (shz, shx, ely, elx), 0-based.
HYDRAULIC_JOINTS = (0, 1, 2, 3)
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


def _scenario_extra(robot: RobotModel, scenario: str) -> StribeckFriction | None:
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
    ctrl = Controller(
        controller_model if controller_model is not None else robot,
        stiffness=stiffness,
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


# ---------------------------------------------------------------------------------------------- friction
@dataclass(frozen=True)
class FrictionExperiment:
    """Single-joint friction runs and fits.

    Attributes:
        fits: one :class:`FrictionFit` per identified joint.
        friction: all joints' d_v, mu_C (joints not run keep ``default``'s values, see
            :func:`run_friction_experiments`); the offsets of the fits are not included (they absorb the
            mean rigid-body model error over each joint's travel).
        plans: the reference of each joint's runs.
        logs: the recorded log of each joint.
        truth: the plant's true friction.
    """

    fits: tuple[FrictionFit, ...]
    friction: FrictionParameters
    plans: dict[int, ConstantVelocityTrajectory]
    logs: dict[int, RobotLog]
    truth: CoulombViscousFriction

    def table(self, joint_names: Sequence[str]) -> list[dict[str, object]]:
        """Rows per identified joint: identified and true mu_C, d_v and relative errors."""
        rows = []
        for f in self.fits:
            mu, dv = self.truth.coulomb[f.joint], self.truth.viscous[f.joint]
            rows.append(
                {
                    "joint": f"{f.joint + 1} ({joint_names[f.joint]})",
                    "mu_C": f.coulomb,
                    "mu_C_true": float(mu),
                    "mu_C_err_pct": 100 * (f.coulomb - mu) / mu if mu else None,
                    "d_v": f.viscous,
                    "d_v_true": float(dv),
                    "d_v_err_pct": 100 * (f.viscous - dv) / dv if dv else None,
                    "offset": f.offset,
                    "points": len(f.points),
                }
            )
        return rows


def _friction_run(
    robot: RobotModel,
    joint: int,
    model: RobotModel,
    speeds: Sequence[float] | None,
    travel: float,
    noise: SensorNoise,
    seed: int,
    true_friction: CoulombViscousFriction | None,
    extra: Any,
    offset: bool,
    progress: bool,
) -> tuple[FrictionFit, ConstantVelocityTrajectory, RobotLog]:
    plan = plan_friction_experiment(robot, joint, speeds=speeds, max_travel=travel)
    log, _ = simulate_log(
        robot,
        plan,
        plan.duration,
        controller_model=model,
        noise=noise,
        seed=seed + 1000 * (joint + 1),
        true_friction=true_friction,
        extra_joint_torque=extra,
        source=f"friction joint {joint + 1}",
        progress=progress,
    )
    fit = identify_joint_friction(
        model,
        joint,
        log.t,
        log.q,
        log.dq,
        log.tau,
        windows=plan.windows,
        position_window=plan.position_window(DEFAULT_SETTLE_TIME),
        offset=offset,
        settle=DEFAULT_SETTLE_TIME,
    )
    return fit, plan, log


def run_friction_experiments(
    robot: RobotModel,
    *,
    joints: Sequence[int] = HYDRAULIC_JOINTS,
    speeds: Sequence[float] | None = None,
    travel: float = 1.5,
    model: RobotModel | None = None,
    offset: bool = True,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    true_friction: CoulombViscousFriction | None = None,
    extra_joint_torque: Any = None,
    default: FrictionParameters | None = None,
    n_jobs: int = 1,
    progress: bool = False,
) -> FrictionExperiment:
    """Constant-velocity runs of each joint in ``joints`` on the plant, and the friction fit of each.

    Args:
        robot: the true arm (plant).
        joints: 0-based joints to run (default: the Atlas arm's hydraulic joints).
        speeds: speeds [rad/s] (default: :data:`~reflexarm.ident.joint_friction.DEFAULT_SPEEDS`).
        travel: travel of each move [rad].
        model: the controller's model, also used to remove the rigid-body torque (default: ``robot``).
        offset: fit an offset too; it absorbs the mean rigid-body model error over the travel (the same
            for every speed and both directions, since each speed runs the same range both ways).
        noise, seed: sensor noise and seed.
        true_friction, extra_joint_torque: the plant's friction (default: the file's) and extra torque.
        default: friction of the joints not run (default: zeros).
        n_jobs: joints run in parallel (joblib processes).
        progress: progress bars.
    """
    model = model if model is not None else robot
    args = (model, speeds, travel, noise, seed, true_friction, extra_joint_torque, offset)
    if n_jobs == 1 or len(joints) == 1:
        runs = [_friction_run(robot, j, *args, progress) for j in joints]
    else:
        from joblib import Parallel, delayed

        runs = Parallel(n_jobs=n_jobs)(delayed(_friction_run)(robot, j, *args, False) for j in joints)
    fits = tuple(r[0] for r in runs)
    fr = friction_from_fits(fits, robot.n, default=default)
    fr = FrictionParameters(fr.viscous, fr.coulomb, None)
    truth = true_friction if true_friction is not None else robot.friction
    return FrictionExperiment(
        fits=fits,
        friction=fr,
        plans={j: r[1] for j, r in zip(joints, runs, strict=True)},
        logs={j: r[2] for j, r in zip(joints, runs, strict=True)},
        truth=truth,
    )


# ---------------------------------------------------------------------------------------------- the study
@dataclass(frozen=True)
class IdentificationStudy:
    """Sequential against combined identification on the simulated plant (the Table I analogue).

    Attributes:
        scenario: ``"table1"`` or ``"stribeck"``.
        friction: the single-joint experiments.
        excitation: the excitation design (optimized Fourier trajectory, condition numbers).
        validation_trajectory: the (different) validation trajectory.
        results: ``{"combined": beta_I, "sequential": beta_II}`` identifications from every sample (as
            in the paper).
        validations: the validation torques of both.
        results_moving, validations_moving: the same with the rows of non-moving joints
            (|dq_j| < :data:`MOVING_SPEED`) left out of the identification (``min_speed``).
        true_base: the plant's true base parameters.
        notes: the scenario's plant description.
        plant_extra: the extra plant torque of the scenario (None for ``"table1"``).
    """

    scenario: str
    robot: RobotModel
    friction: FrictionExperiment
    excitation: ExcitationDesign
    validation_trajectory: FourierTrajectory
    identification_log: RobotLog
    validation_log: RobotLog
    results: dict[str, DynamicsIdentification]
    validations: dict[str, TorqueValidation]
    results_moving: dict[str, DynamicsIdentification]
    validations_moving: dict[str, TorqueValidation]
    true_base: np.ndarray
    notes: dict[str, object] = field(default_factory=dict)
    plant_extra: StribeckFriction | None = None

    def table(self, *, moving: bool = False) -> list[dict[str, object]]:
        """Table I analogue: per joint, validation MSE of both methods and the friction parameters.

        ``mse_*``: over every validation sample (as the paper); ``mse_moving_*``: over the samples where
        the joint moves (|dq_j| >= :data:`MOVING_SPEED`). ``moving=True``: the variant identified
        without the non-moving rows.
        """
        names = self.robot.joint_names
        res = self.results_moving if moving else self.results
        val = self.validations_moving if moving else self.validations
        comb, seq = res["combined"], res["sequential"]
        vc, vs = val["combined"], val["sequential"]
        mc, ms = vc.mse_moving(MOVING_SPEED), vs.mse_moving(MOVING_SPEED)
        rows = []
        for j in range(self.robot.n):
            rows.append(
                {
                    "joint": f"{j + 1} ({names[j]})",
                    "mse_combined": float(vc.mse[j]),
                    "mse_sequential": float(vs.mse[j]),
                    "mse_moving_combined": float(mc[j]),
                    "mse_moving_sequential": float(ms[j]),
                    "mu_C_single_joint": float(seq.friction.coulomb[j]),
                    "d_v_single_joint": float(seq.friction.viscous[j]),
                    "mu_C_combined": float(comb.friction.coulomb[j]),
                    "d_v_combined": float(comb.friction.viscous[j]),
                    "mu_C_true": float(self.friction.truth.coulomb[j]),
                    "d_v_true": float(self.friction.truth.viscous[j]),
                }
            )
        return rows

    def hydraulic_mse(self, *, moving: bool = False) -> dict[str, float]:
        """Mean validation MSE over the hydraulic joints, per method [Nm^2]: over all validation samples
        (``<method>``) and over the moving ones (``<method>_moving_samples``)."""
        idx = list(HYDRAULIC_JOINTS)
        val = self.validations_moving if moving else self.validations
        out = {m: float(np.mean(v.mse[idx])) for m, v in val.items()}
        out.update({f"{m}_moving_samples": float(np.mean(v.mse_moving(MOVING_SPEED)[idx])) for m, v in val.items()})
        return out


def _validation_trajectory(robot: RobotModel, seed: int, base_frequency: float) -> FourierTrajectory:
    """A random (unoptimized) Fourier trajectory within the limits: different from the excitation."""
    design = optimize_excitation(robot, base_frequency=base_frequency, maxiter=0, seed=seed)
    return design.initial


def run_identification_study(
    robot: RobotModel | str = "atlas_v5_left_arm",
    *,
    scenario: str = "table1",
    excitation: ExcitationDesign | None = None,
    periods: int = 2,
    friction_speeds: Sequence[float] | None = None,
    friction_joints: Sequence[int] = tuple(range(7)),
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    maxiter: int = 100,
    n_jobs: int = 1,
    progress: bool = False,
) -> IdentificationStudy:
    """Friction runs, excitation run and validation run on the plant; combined vs sequential.

    The user's situation is simulated: the controller runs on a perturbed nominal model (+-10 % errors,
    :func:`reflexarm.robots.perturb_model`), which is also the model the single-joint experiments
    remove the rigid-body torque with (its mean error over each travel is absorbed by the fit's offset).

    Args:
        robot: the true arm (default: the Atlas arm).
        scenario: ``"table1"`` or ``"stribeck"`` (plant friction, see the module docstring).
        excitation: the excitation design (default: optimized here with ``maxiter``).
        periods: periods of the excitation run (the validation run has as many of its own trajectory).
        friction_speeds: speeds of the single-joint runs.
        friction_joints: joints with single-joint runs (default: all seven, as in Table I).
        noise, seed: sensor noise and seed.
        n_jobs: parallel single-joint runs.
        progress: progress bars.
    """
    robot = load_robot(robot) if isinstance(robot, str) else robot
    extra = _scenario_extra(robot, scenario)
    nominal = perturb_model(robot, NOMINAL_ERROR_LEVEL, seed=seed)
    base = compute_base_parameters(robot)
    fr = run_friction_experiments(
        robot,
        joints=friction_joints,
        speeds=friction_speeds,
        model=nominal,
        noise=noise,
        seed=seed,
        extra_joint_torque=extra,
        default=FrictionParameters.from_model(nominal.friction),
        n_jobs=n_jobs,
        progress=progress,
    )
    if excitation is None:
        excitation = optimize_excitation(robot, base=base, maxiter=maxiter, seed=seed)
    traj = excitation.trajectory.with_periods(periods)
    vtraj = _validation_trajectory(robot, seed + 1, excitation.trajectory.base_frequency).with_periods(periods)
    ident_raw, _ = simulate_log(
        robot,
        traj,
        traj.duration,
        controller_model=nominal,
        noise=noise,
        seed=seed + 1,
        extra_joint_torque=extra,
        source="excitation",
        progress=progress,
    )
    valid_raw, _ = simulate_log(
        robot,
        vtraj,
        vtraj.duration,
        controller_model=nominal,
        noise=noise,
        seed=seed + 2,
        extra_joint_torque=extra,
        source="validation",
        progress=progress,
    )
    ident = preprocess_log(ident_raw)
    valid = preprocess_log(valid_raw)

    def both(min_speed: float) -> dict[str, DynamicsIdentification]:
        return {
            "combined": identify_dynamics(robot, ident, method="combined", base=base, min_speed=min_speed),
            "sequential": identify_dynamics(
                robot, ident, method="sequential", friction=fr.friction, base=base, min_speed=min_speed
            ),
        }

    results = both(0.0)
    results_moving = both(MOVING_SPEED)
    validations = {m: validate_model(r, robot, valid, label=m) for m, r in results.items()}
    validations_moving = {m: validate_model(r, robot, valid, label=m) for m, r in results_moving.items()}
    return IdentificationStudy(
        scenario=scenario,
        robot=robot,
        friction=fr,
        excitation=excitation,
        validation_trajectory=vtraj,
        identification_log=ident,
        validation_log=valid,
        results=results,
        validations=validations,
        results_moving=results_moving,
        validations_moving=validations_moving,
        true_base=base.base_from_standard(robot.inertial_parameters()),
        notes={"scenario": scenario, "extra_joint_torque": None if extra is None else extra.describe()},
        plant_extra=extra,
    )


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
