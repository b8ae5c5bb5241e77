"""The parameters the C++ core (``reflexarm._core``) is configured with, from a checked
:class:`~reflexarm.control.Controller` (its construction, the compiled closed loop, the benches).

Kept apart from :mod:`reflexarm.control.controller`, which imports it (and re-exports :func:`core_params`); it
imports nothing of the package, so no import circle passes through it."""

from __future__ import annotations

from dataclasses import fields
from types import ModuleType
from typing import Any

import numpy as np

__all__ = ["core_params"]


def core_params(ctrl: Any, core: ModuleType) -> Any:
    """The core's ``ControllerParams`` for ``ctrl``, a :class:`~reflexarm.control.Controller` whose Python-side
    checks have passed (typed ``Any``: naming the class here would make the two modules import each other)."""
    p = core.ControllerParams()
    robot, imp = ctrl.robot, ctrl.impedance
    p.stiffness, p.damping_ratio = imp.gains.stiffness.copy(), imp.gains.damping_ratio.copy()
    p.observer_gain = ctrl.observer.observer_gain.copy()
    det = ctrl.detection_observer
    p.detection_observer_gain = np.zeros(0) if det is None else det.observer_gain.copy()
    p.detection_kappa_f = ctrl.detection_kappa_f
    band = ctrl.detection_friction_velocity_band
    p.detection_friction_velocity_band = 0.0 if band is None else band
    kf = ctrl.detection_filter_gain
    p.detection_filter_gain = np.zeros(0) if kf is None else kf.copy()
    p.threshold = np.zeros(0) if ctrl.detector is None else ctrl.detector.threshold.copy()
    p.reaction = ctrl.reaction
    p.contact_reaction = ctrl.contact_reaction
    p.reaction_params = ctrl.reaction_settings.to_core(core)
    p.observer_discretization = ctrl.observer_discretization
    p.kappa_f, p.kappa_eps, p.kappa_ext = ctrl._kappa_init
    p.residual_limit, p.switch_time, p.dt = ctrl.residual_limit, ctrl.switch_time, ctrl.dt
    p.damping_update_period = imp.damping_update_period
    fr = robot.friction
    p.friction_coulomb, p.friction_viscous = fr.coulomb.copy(), fr.viscous.copy()
    p.friction_velocity_band = fr.velocity_band
    if robot.has_springs:
        p.spring_stiffness = np.array(robot.spring_stiffness, dtype=float)
        p.spring_reference = np.array(robot.spring_reference, dtype=float)
    p.sensor_frame_id = robot.sensor_frame_id
    p.torque_limit = ctrl.torque_limit.copy()
    p.torque_rate_limit = np.zeros(0) if ctrl.torque_rate_limit is None else ctrl.torque_rate_limit.copy()
    bounds = core.InputBounds()
    for f in fields(ctrl.input_bounds):
        setattr(bounds, f.name, getattr(ctrl.input_bounds, f.name))
    p.input_bounds = bounds
    p.period_band_low, p.period_band_high = ctrl.period_band
    return p
