"""Simulated free-motion logs for threshold tuning: what a real arm's logger records (default: the Atlas arm).

The free-motion run of :func:`reflexarm.experiments.collision.free_motion_false_alarms` (the paper's
sensor noise, the controller's model with +-10 % errors, no obstacle) with every *measurement* the
controller received recorded (t, q, dq, tau_m, wrist wrench, all with their noise): the log a robot
would write, in the schema of :mod:`reflexarm.logs.files`. The same run counts its false alarms
online at a given threshold, so a proposal can be checked on a held-out run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel

if TYPE_CHECKING:
    from reflexarm.tuning.replay import ObserverSettings

__all__ = ["FreeMotionRun", "record_free_motion_log"]


@dataclass(frozen=True)
class FreeMotionRun:
    """A recorded free-motion run.

    Attributes:
        log: the measurements, as a robot log (source names the run's seeds).
        false_alarm_events: separate detections at ``threshold`` during the run (rising edges).
        false_alarm_ticks: ticks with the collision flag set.
        first_false_alarm_s: time of the first detection [s] or None.
        max_abs_residual: max |residual| per joint over the run [Nm].
        threshold: zeta per joint [Nm] the run detected with.
    """

    log: RobotLog
    false_alarm_events: int
    false_alarm_ticks: int
    first_false_alarm_s: float | None
    max_abs_residual: np.ndarray
    threshold: np.ndarray

    def as_dict(self) -> dict[str, object]:
        """JSON-ready counts (joints 1-based in the keys)."""
        return {
            "source": self.log.source,
            "duration_s": float(self.log.t[-1] - self.log.t[0]),
            "false_alarm_events": self.false_alarm_events,
            "false_alarm_ticks": self.false_alarm_ticks,
            "first_false_alarm_s": self.first_false_alarm_s,
            "threshold_Nm": {str(j + 1): float(v) for j, v in enumerate(self.threshold)},
            "max_abs_residual_Nm": {str(j + 1): float(v) for j, v in enumerate(self.max_abs_residual)},
        }


def record_free_motion_log(
    duration: float,
    *,
    motion: str = "hydraulic",
    model_error: float | None = None,
    model_seed: int = 0,
    model: RobotModel | None = None,
    seed: int = 0,
    threshold: npt.ArrayLike = 11.0,
    observer_gain: float = 5.0,
    progress: bool = False,
    robot: RobotModel | None = None,
    settings: ObserverSettings | None = None,
) -> FreeMotionRun:
    """Run free motion (default on the built-in Atlas arm) and record the controller's measurements.

    Args:
        duration: simulated time [s].
        motion: a free motion of :func:`reflexarm.experiments.collision.free_motion_trajectory` ("demo",
            "hydraulic" on Atlas; "demo" or "loaded" on another arm).
        model_error, model_seed, model: the controller's model, as in
            :func:`reflexarm.experiments.collision.controller_model` (default +-10 %, seed 0).
        seed: seed of the sensor noise (the paper's levels).
        threshold: zeta [Nm], scalar or per joint, the online detector counts false alarms with
            (reaction "none": detection does not change the motion).
        observer_gain: k_o [1/s] (without ``settings``).
        progress: show a progress bar.
        robot: the plant's arm (default the built-in Atlas arm).
        settings: the observers the online detector runs (its k_o, detection observer, kappas, form, friction
            band, second stage), so that its residual is the one a replay with these settings gives (None: the
            first observer alone at ``observer_gain``, Euler, the paper's).
    """
    from reflexarm.control import Controller, detection_friction
    from reflexarm.control.law_stability import experiment_stiffness
    from reflexarm.experiments.collision import ROBOT, controller_model, free_motion_trajectory
    from reflexarm.robots import load_robot
    from reflexarm.sim import PAPER_NOISE, Plant
    from reflexarm.tuning.replay import ObserverSettings

    robot = load_robot(ROBOT) if robot is None else robot
    ctrl_model, info = controller_model(robot, model_error, model_seed, model)
    traj = free_motion_trajectory(duration, motion, robot)
    plant = Plant(robot, noise=PAPER_NOISE, seed=seed)
    plant.reset(traj.sample(0.0).q_d)
    s = ObserverSettings(observer_gain=observer_gain) if settings is None else settings
    stiffness = experiment_stiffness(ctrl_model, 300.0)
    ctrl = Controller(
        ctrl_model, stiffness=stiffness, threshold=threshold, reaction="none", observer_gain=s.observer_gain,
        detection_observer_gain=s.detection_observer_gain, kappa_f=s.kappa_f, kappa_ext=s.kappa_ext,
        kappa_eps=s.kappa_eps, observer_discretization=s.observer_discretization,
        detection_filter_gain=s.detection_filter_gain, **detection_friction(s.detection_friction_band),
    )  # fmt: skip
    n = robot.n
    # the compiled loop keeps what the controller measured on every tick (the Python loop if it cannot)
    from reflexarm.sim.measurement_log import record_measurements

    stats, m = record_measurements(plant, ctrl, traj, duration, progress=progress)
    source = f"free-motion {motion} {duration:g} s (noise seed {seed}, model {info})"
    log = RobotLog(t=m["t"], q=m["q"], dq=m["dq"], tau=m["tau_m"], wrench=m["wrench"], source=source)
    thr = np.broadcast_to(np.asarray(threshold, dtype=float), (n,)).copy()
    return FreeMotionRun(
        log=log,
        false_alarm_events=stats.collision_events,
        false_alarm_ticks=stats.collision_ticks,
        first_false_alarm_s=stats.first_collision_t,
        max_abs_residual=stats.max_abs_residual.copy(),
        threshold=thr,
    )
