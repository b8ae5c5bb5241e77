"""Why an excitation is badly conditioned: the condition number of its base regressor, and the stall report of a
run that ends above :data:`STALLED_CONDITION` (the optimizer's message, its progress, the regressor's weakest
direction)."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.optimize

from reflexarm.ident.estimation.base_parameters import BaseParameters, compute_base_parameters, condition_number
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.robots.robot_model import RobotModel

__all__ = ["STALLED_CONDITION", "ExcitationStalledWarning", "diagnose_stall", "regressor_condition"]

#: An optimized condition number above this is reported as stalled. Measured optimized values: 28 on the
#: Gen3-like arm (L = 5, 100 iterations), 48-153 on the Atlas arm (L = 4, 12 iterations, per CPU); a
#: regressor at 1e3 amplifies a 1 % torque error into up to 10 x its share on some combination.
STALLED_CONDITION = 1e3
#: Over the last :data:`_STALL_WINDOW` iterations, an improvement of the condition number below this
#: fraction means the optimizer has stopped making progress.
STALL_PROGRESS = 0.01
_STALL_WINDOW = 10


class ExcitationStalledWarning(UserWarning):
    """The excitation optimization ended with a badly conditioned regressor; the message says why.

    Attributes:
        condition: the condition number reached; weakest: the base combinations of the weakest direction.
    """

    def __init__(self, message: str, *, condition: float, weakest: tuple[str, ...]) -> None:
        super().__init__(message)
        self.condition = condition
        self.weakest = weakest


def diagnose_stall(
    robot: RobotModel,
    base: BaseParameters,
    trajectory: FourierTrajectory,
    condition: float,
    history: list[float],
    res: scipy.optimize.OptimizeResult,
    n_samples: int,
) -> str:
    """Why a run ended badly conditioned ("" if it did not): the optimizer's message, its progress over
    the last iterations, and the base combinations of the regressor's weakest direction; warns."""
    if condition <= STALLED_CONDITION:
        return ""
    t = np.arange(n_samples) * trajectory.period / n_samples
    q, dq, ddq = trajectory.evaluate(t)
    W = base.select(BatchRegressor(robot).compute_regressor(q, dq, ddq)).reshape(-1, base.n_base)
    norms = np.linalg.norm(W, axis=0)
    _, sv, vt = np.linalg.svd(W, full_matrices=False)  # the cost's own (unscaled) regressor
    order = np.argsort(-np.abs(vt[-1]))[:3]
    names = base.base_names(max_terms=2)
    weakest = tuple(names[k] for k in order)
    recent = history[-_STALL_WINDOW:]
    progress = (recent[0] - recent[-1]) / recent[0] if len(recent) >= 2 else 0.0
    small = int(np.argmin(norms))
    stalled = len(recent) >= 2 and progress < STALL_PROGRESS
    text = (
        f"excitation optimization ended at condition number {condition:.4g} (> {STALLED_CONDITION:.0e}) after "
        f"{len(history)} iteration(s) ({res.get('message', '')}"
        + (f"; the last {len(recent)} improved it by {100 * progress:.2g} %: stalled" if stalled else "")
        + "). The motion cannot excite the weakest direction of the base regressor, mostly "
        + "; ".join(f"[{w}]" for w in weakest)
        + f" (singular values {sv[0]:.3g} .. {sv[-1]:.3g}; the smallest column, [{names[small]}], is "
        f"{norms[small] / norms.max():.2g} of the largest). "
        + (base.note + "." if base.note else "A column far smaller than the others is a combination no motion "
           "excites (e.g. an axis nearly, not exactly, aligned: see the base parameters 'reflexarm excite' prints); "
           "otherwise raise --maxiter.")
    )  # fmt: skip
    warnings.warn(ExcitationStalledWarning(text, condition=condition, weakest=weakest), stacklevel=3)
    return text


def regressor_condition(
    robot: RobotModel, trajectory: FourierTrajectory, *, base: BaseParameters | None = None, n_samples: int = 100
) -> float:
    """Condition number of the base regressor stacked over ``n_samples`` samples of one period."""
    base = base if base is not None else compute_base_parameters(robot)
    t = np.arange(n_samples) * trajectory.period / n_samples
    q, dq, ddq = trajectory.evaluate(t)
    W = base.select(BatchRegressor(robot).compute_regressor(q, dq, ddq)).reshape(-1, base.n_base)
    return condition_number(W)
