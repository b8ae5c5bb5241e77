"""Single-joint constant-velocity friction experiments on the simulated plant (Sec. II-D 2, Fig. 4/5).

:func:`run_friction_experiments` runs each joint at a set of constant speeds in both directions with
the impedance controller and fits Coulomb + viscous friction (Table I) per joint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from reflexarm.errors import ConfigError
from reflexarm.experiments.ident_runs import hydraulic_joints, simulate_log
from reflexarm.ident import (
    ConstantVelocityTrajectory,
    FrictionFit,
    FrictionParameters,
    RobotLog,
    friction_from_fits,
    identify_joint_friction,
    plan_friction_experiment,
)
from reflexarm.ident.friction.joint_friction import DEFAULT_SETTLE_TIME
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim import PAPER_NOISE, SensorNoise

__all__ = ["FrictionExperiment", "run_friction_experiments"]


@dataclass(frozen=True)
class FrictionExperiment:
    """Single-joint friction runs and fits.

    Attributes:
        fits: one :class:`FrictionFit` per identified joint.
        friction: all joints' d_v, mu_C (joints not run: ``default``'s values if given, else not known, NaN,
            see :func:`run_friction_experiments`); the offsets of the fits are not included (they absorb the
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


def _check_joints(joints: Sequence[int], robot: RobotModel) -> tuple[int, ...]:
    """``joints`` as a tuple of 0-based indices of ``robot``; ConfigError naming the bad ones (1-based)."""
    js = tuple(int(j) for j in joints)
    bad = [j for j in js if not 0 <= j < robot.n]
    if bad or not js:
        raise ConfigError(
            f"friction joints {[j + 1 for j in bad] if bad else '(none)'} (1-based) are not joints of "
            f"{robot.name!r}; it has joints 1..{robot.n} ({', '.join(robot.joint_names)})"
        )
    return js


def run_friction_experiments(
    robot: RobotModel,
    *,
    joints: Sequence[int] | None = None,
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
        joints: 0-based joints to run (default: the hydraulic joints on the Atlas arm, every joint on
            other arms; see :func:`~reflexarm.experiments.ident_runs.hydraulic_joints`).
        speeds: speeds [rad/s] (default: :data:`~reflexarm.ident.friction.joint_friction.DEFAULT_SPEEDS`).
        travel: travel of each move [rad].
        model: the controller's model, also used to remove the rigid-body torque (default: ``robot``).
        offset: fit an offset too; it absorbs the mean rigid-body model error over the travel (the same
            for every speed and both directions, since each speed runs the same range both ways).
        noise, seed: sensor noise and seed.
        true_friction, extra_joint_torque: the plant's friction (default: the file's) and extra torque.
        default: friction of the joints not run (default: none; they are not known, NaN in ``friction``:
            :func:`~reflexarm.ident.identify_dynamics` then estimates them in the sequential method).
        n_jobs: joints run in parallel (joblib processes).
        progress: progress bars.
    """
    model = model if model is not None else robot
    if joints is None:
        joints = hydraulic_joints(robot) or tuple(range(robot.n))
    joints = _check_joints(joints, robot)
    args = (model, speeds, travel, noise, seed, true_friction, extra_joint_torque, offset)
    if n_jobs == 1 or len(joints) == 1:
        runs = [_friction_run(robot, j, *args, progress) for j in joints]
    else:
        from joblib import Parallel, delayed

        runs = Parallel(n_jobs=n_jobs)(delayed(_friction_run)(robot, j, *args, False) for j in joints)
    fits = tuple(r[0] for r in runs)
    fr = friction_from_fits(fits, robot.n, default=default)
    fr = FrictionParameters(fr.viscous, fr.coulomb, None)
    if default is None:  # friction_from_fits puts 0 for the joints not run: not a friction value
        fr = fr.restricted_to(joints)
    truth = true_friction if true_friction is not None else robot.friction
    return FrictionExperiment(
        fits=fits,
        friction=fr,
        plans={j: r[1] for j, r in zip(joints, runs, strict=True)},
        logs={j: r[2] for j, r in zip(joints, runs, strict=True)},
        truth=truth,
    )
