"""Validation of an identified model on a table log read in blocks (``reflexarm validate`` on long logs).

:func:`validate_streamed` is :func:`~reflexarm.ident.estimation.validation.validate_model` with the states of
:func:`~reflexarm.logs.preprocess_log` for a log on a uniform grid (gaps allowed: segments), the measured torque
the raw one: each preprocessed block's states are the states at the log's own samples, so the prediction and
the error of every sample are those of the whole log's validation (to the preprocessing's rounding, see
:mod:`reflexarm.logs.blocks`). What is kept: per joint, the sums of the squared error and the mean and
spread of the measured torque (merged block by block, Chan et al.'s pairwise update), and every k-th sample
for the plot (at most :data:`PLOT_SAMPLES`). Logs that are resampled, lose a segment, or carry a wrist wrench
(whose use the whole validation decides) are not streamed (:class:`~reflexarm.logs.blocks.NotStreamable`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reflexarm.ident.estimation.result import DynamicsIdentification
from reflexarm.ident.estimation.validation import (
    EXACT_SIGN,
    TorqueValidation,
    describe_friction_model,
    validation_table,
)
from reflexarm.logs.blocks import DEFAULT_BLOCK_ROWS, NotStreamable, StreamedTable
from reflexarm.logs.preprocessing import DEFAULT_CUTOFF_HZ, plan_preprocessing
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = ["PLOT_SAMPLES", "ValidationSummary", "validate_streamed"]

#: Samples of the plotted series (every k-th sample of the log).
PLOT_SAMPLES = 200_000


@dataclass(frozen=True)
class ValidationSummary:
    """The numbers of a :class:`~reflexarm.ident.estimation.validation.TorqueValidation` without its arrays.

    Attributes:
        mse: per joint [Nm^2]; torque_std: std of the measured torque per joint [Nm]; samples: N;
        label, friction_model: as in TorqueValidation; plotted: every k-th sample (for the figure).
    """

    mse: np.ndarray
    torque_std: np.ndarray
    samples: int
    label: str
    friction_model: str
    plotted: TorqueValidation

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(self.mse)

    @property
    def nrmse(self) -> np.ndarray:
        return self.rmse / np.maximum(self.torque_std, 1e-300)

    @property
    def pooled_rmse(self) -> float:
        return float(np.sqrt(np.mean(self.mse)))

    def table(self, joint_names: Sequence[str] | None = None) -> list[dict[str, object]]:
        """Rows ``{joint, mse, rmse, nrmse, torque_std}`` per joint, as :meth:`TorqueValidation.table`."""
        return validation_table(self.mse, self.torque_std, joint_names)


def validate_streamed(
    result: DynamicsIdentification,
    robot: RobotModel,
    table: StreamedTable,
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    block_rows: int = DEFAULT_BLOCK_ROWS,
    label: str | None = None,
    friction: CoulombViscousFriction | None = None,
) -> ValidationSummary:
    """:func:`~reflexarm.ident.estimation.validation.validate_model` (``friction`` as there) of ``result`` on
    ``table`` with its preprocessed states, block by block; the log held against the robot on the way."""
    from reflexarm.ident.estimation.streaming import _grid, checked_blocks

    if table.has_wrench:
        raise NotStreamable(f"{table.source}: a log with a wrist wrench is validated whole (its use is decided there)")
    plan = plan_preprocessing(table.t, table.source, cutoff_hz=cutoff_hz, has_ddq=table.has_ddq)
    if plan.resample or plan.size != len(table):
        raise NotStreamable(f"{table.source}: a log that is resampled or loses a segment is validated whole")
    if friction is not None and friction.coulomb.shape != (result.n,):
        from reflexarm.errors import IdentificationError

        raise IdentificationError(
            f"the friction model to score has {friction.coulomb.size} joints; the identification has {result.n}"
        )
    stride = max(len(table) // PLOT_SAMPLES, 1)
    n = robot.n
    count, mean, m2, e2 = 0, np.zeros(n), np.zeros(n), np.zeros(n)
    shown: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    start = 0
    for block in checked_blocks(table, plan, robot, block_rows, _grid(plan), check_states=False):
        assert block.ddq is not None
        pred = result.compute_torque(robot, block.q, block.dq, block.ddq)
        if friction is not None:
            pred += friction.compute_torque(block.dq) - result.friction.compute_torque(block.dq)
        meas = block.measured_torque
        e2 += np.sum((pred - meas) ** 2, axis=0)
        m = len(block)  # Chan et al.: merge the block's mean and sum of squared deviations
        b_mean = meas.mean(axis=0)
        b_m2 = np.sum((meas - b_mean) ** 2, axis=0)
        delta = b_mean - mean
        mean = mean + delta * m / (count + m)
        m2 = m2 + b_m2 + delta**2 * count * m / (count + m)
        count += m
        rows = np.arange((-start) % stride, m, stride)
        shown.append((block.t[rows], meas[rows], pred[rows]))
        start += m
    t, meas_k, pred_k = (np.concatenate([s[i] for s in shown]) for i in range(3))
    how = EXACT_SIGN if friction is None else describe_friction_model(friction)
    name = label if label is not None else result.method
    return ValidationSummary(
        e2 / count, np.sqrt(m2 / count), count, name, how, TorqueValidation(t, meas_k, pred_k, name, None, how)
    )
