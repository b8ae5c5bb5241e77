"""The collision node's controller from its configuration: the robot, the controller's model (robot file,
identified model, or the robot perturbed for a simulation), the thresholds (as ``--threshold`` reads them) and a
warm-up so that the first live tick carries no first-use cost."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from reflexarm.control import Controller, detection_friction
from reflexarm.control.law_stability import UnstableLawWarning, check_law_stability
from reflexarm.robots.robot_model import RobotModel
from reflexarm.ros.config import MonitorConfig
from reflexarm.signals import Measurement, Reference

__all__ = ["build_controller", "load_models"]


def load_models(config: MonitorConfig) -> tuple[RobotModel, RobotModel]:
    """(the robot, the controller's model: the identified model file, or the robot perturbed by model_error)."""
    from reflexarm.robots import load_robot, perturb_model

    robot = load_robot(config.robot)
    if config.model_file:
        from reflexarm.ident import load_identified_model

        return robot, load_identified_model(Path(config.model_file), robot)
    if config.model_error > 0:
        return robot, perturb_model(robot, config.model_error, config.model_seed)
    return robot, robot


def build_controller(config: MonitorConfig, model: RobotModel) -> Controller:
    """The controller of ``config`` on ``model`` (thresholds as ``--threshold`` reads them), warmed up: a few ticks
    at rest, then :meth:`Controller.reset` (after which it runs as a fresh one, bitwise), so that the first real
    tick carries no first-use cost."""
    from reflexarm._cli.threshold_files import read_threshold, tuned_filter_gain, tuned_friction_band

    detecting = config.detection_observer_gain or None
    gain = detecting or config.observer_gain
    zeta, source, tuned = read_threshold(config.threshold, model, gain)
    if tuned is not None and not math.isclose(tuned, gain, rel_tol=1e-9):
        warnings.warn(
            f"threshold {source} was tuned for a detecting observer gain of {tuned:g} 1/s; this node detects with "
            f"{gain:g} 1/s (set observer_gain or detection_observer_gain to match)",
            stacklevel=2,
        )
    band = config.detection_friction_band or None
    if band is None and source != "command line":  # levels tuned with the detecting observer's own friction
        band = tuned_friction_band(config.threshold)
    kf = config.detection_filter_gain or None
    if kf is None and source != "command line":  # levels tuned on the residual through the second stage
        kf = tuned_filter_gain(config.threshold)
    with warnings.catch_warnings():  # monitor: the law's torque is never applied; control: refused below
        warnings.simplefilter("ignore", UnstableLawWarning)
        controller = Controller(
            model,
            stiffness=config.stiffness,
            observer_gain=config.observer_gain,
            detection_observer_gain=detecting,
            **detection_friction(band),
            detection_filter_gain=kf,
            threshold=zeta,
            reaction=config.reaction,
            observer_discretization=config.observer_discretization,
        )
    if config.mode == "control":  # the node commands this law's torque: an unstable one is refused
        imp = controller.impedance
        check_law_stability(model, imp.stiffness, imp.damping_ratio, controller.dt)
    q = np.clip(np.zeros(model.n), model.lower_limit, model.upper_limit)
    rest = Measurement(0.0, q, np.zeros(model.n), model.compute_gravity(q), np.zeros(6), np.asarray(model.gravity))
    for k in range(12):
        controller.step(rest._replace(t=k * controller.dt), Reference.hold(q))
    controller.reset()
    return controller
