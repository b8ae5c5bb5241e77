"""Validation of an identified model: measured against predicted torques on a log (:func:`validate_model`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.result import DynamicsIdentification
from reflexarm.logs._measured_torque import _rhs
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = ["EXACT_SIGN", "TorqueValidation", "describe_friction_model", "validate_model", "validation_table"]

#: :attr:`TorqueValidation.friction_model` of a prediction with the identification's own friction model.
EXACT_SIGN = "as identified: d_v dq + mu_C sgn(dq) (exact sign) [+ offsets]"


def describe_friction_model(friction: CoulombViscousFriction) -> str:
    """How a :class:`CoulombViscousFriction` (the controller's model) computes the friction torque."""
    return (
        f"as the controller uses it: d_v dq + mu_C clip(dq / {friction.velocity_band:g} rad/s, -1, 1) "
        "(Coulomb smoothed inside the velocity band; negative coefficients clipped to 0, no offsets)"
    )


@dataclass(frozen=True)
class TorqueValidation:
    """Measured against predicted torques on a log (ideally not the one identified on).

    Attributes:
        t: time (N,) [s]; measured, predicted: (N, n) [Nm]; dq: the velocities used (N, n) [rad/s].
        mse: per joint [Nm^2]; rmse: per joint [Nm]; nrmse: rmse / std(measured) per joint [-].
        pooled_rmse: over all joints and samples [Nm].
        label: which model (e.g. ``"sequential"``).
        friction_model: which friction model the prediction holds (:data:`EXACT_SIGN` or the one given to
            :func:`validate_model`, e.g. the controller's with its velocity band).
    """

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    label: str = ""
    dq: np.ndarray | None = None
    friction_model: str = ""

    @property
    def error(self) -> np.ndarray:
        return self.predicted - self.measured

    def mse_moving(self, min_speed: float) -> np.ndarray:
        """MSE per joint over the samples where that joint moves, |dq_j| >= ``min_speed`` [Nm^2]; NaN for a joint
        without such a sample (not 0: there is nothing to average)."""
        if self.dq is None:
            raise IdentificationError("this validation has no velocities; build it with validate_model")
        keep = np.abs(self.dq) >= min_speed
        e2 = np.where(keep, self.error**2, 0.0)
        count = keep.sum(axis=0)
        return np.where(count > 0, e2.sum(axis=0) / np.maximum(count, 1), np.nan)

    @property
    def mse(self) -> np.ndarray:
        return np.mean(self.error**2, axis=0)

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(self.mse)

    @property
    def nrmse(self) -> np.ndarray:
        return self.rmse / np.maximum(self.measured.std(axis=0), 1e-300)

    @property
    def pooled_rmse(self) -> float:
        return float(np.sqrt(np.mean(self.error**2)))

    def table(self, joint_names: Sequence[str] | None = None) -> list[dict[str, object]]:
        """Rows ``{joint, mse, rmse, nrmse, std}`` per joint."""
        return validation_table(self.mse, self.measured.std(axis=0), joint_names)


def validation_table(
    mse: np.ndarray, torque_std: np.ndarray, joint_names: Sequence[str] | None = None
) -> list[dict[str, object]]:
    """Rows ``{joint, mse, rmse, nrmse, torque_std}`` per joint from the per-joint MSE [Nm^2] and the measured
    torque's std [Nm] (nrmse = rmse / std); joints named 1..n without ``joint_names``."""
    names = list(joint_names) if joint_names is not None else [str(j + 1) for j in range(mse.size)]
    rmse = np.sqrt(mse)
    nrmse = rmse / np.maximum(torque_std, 1e-300)
    return [
        {
            "joint": names[j],
            "mse": float(mse[j]),
            "rmse": float(rmse[j]),
            "nrmse": float(nrmse[j]),
            "torque_std": float(torque_std[j]),
        }
        for j in range(len(names))
    ]


def validate_model(
    result: DynamicsIdentification,
    robot: RobotModel,
    log: RobotLog,
    *,
    states: RobotLog | None = None,
    label: str | None = None,
    friction: CoulombViscousFriction | None = None,
) -> TorqueValidation:
    """Predict the torques of ``log`` with ``result`` and compare with its measured (unfiltered) torques.

    Args:
        result: an identification.
        robot: the arm (kinematics).
        log: the validation log; its measured torque is the reference (``log.measured_torque``).
        states: where to take q, dq, ddq from if not from ``log`` itself (e.g. a filtered copy on a
            uniform grid); they are interpolated to ``log.t``.
        label: name of the model in plots and tables (default: the method).
        friction: score this friction model instead of the result's own (exact-sign Coulomb, offsets): e.g.
            the controller's, ``load_identified_model(...).friction`` or ``result.friction.to_model(band)``,
            whose Coulomb torque is smoothed over a velocity band. The rigid-body part is the result's.
    """
    if states is None:
        if log.ddq is None:
            raise IdentificationError(f"{log.source}: validation log has no ddq; preprocess it or pass states=")
        q, dq, ddq = log.q, log.dq, log.ddq
    else:
        if states.ddq is None:
            raise IdentificationError(f"{states.source}: states have no ddq; preprocess them first")
        if log.t[0] < states.t[0] - 1e-9 or log.t[-1] > states.t[-1] + 1e-9:
            raise IdentificationError(
                f"{log.source}: validation times {log.t[0]:.4g}..{log.t[-1]:.4g} s are outside the states' "
                f"{states.t[0]:.4g}..{states.t[-1]:.4g} s"
            )
        _refuse_times_in_gaps(log, states)
        q = _interp_cols(states.t, states.q, log.t)
        dq = _interp_cols(states.t, states.dq, log.t)
        ddq = _interp_cols(states.t, states.ddq, log.t)
    pred = result.compute_torque(robot, q, dq, ddq)
    how = EXACT_SIGN
    if friction is not None:
        if friction.coulomb.shape != (result.n,):
            raise IdentificationError(
                f"the friction model to score has {friction.coulomb.size} joints; the identification has {result.n}"
            )
        pred += friction.compute_torque(dq) - result.friction.compute_torque(dq)
        how = describe_friction_model(friction)
    meas = log.measured_torque
    if log.wrench is not None:  # + J^T F when the wrench explains the error (not when it is only noise)
        from reflexarm.ident.estimation.wrist_wrench import validation_reference

        wrench_torque = _rhs(robot, replace(log, tau=np.zeros_like(meas), tau_raw=None))
        meas, decision = validation_reference(wrench_torque, meas, pred)
        how = f"{how}; {decision.reason}"
    return TorqueValidation(
        log.t.copy(), meas.copy(), pred, label if label is not None else result.method, dq.copy(), how
    )


def _refuse_times_in_gaps(log: RobotLog, states: RobotLog) -> None:
    """States split at long gaps (:func:`~reflexarm.ident.preprocess_log`) have no values inside a gap;
    interpolating there would invent q, dq, ddq, so validation times inside one are refused."""
    steps = np.diff(states.t)
    gaps = np.flatnonzero(steps > 1.5 * np.median(steps))
    if not gaps.size:
        return
    idx = np.searchsorted(states.t, log.t, side="right") - 1
    idx = np.clip(idx, 0, steps.size - 1)
    inside = np.isin(idx, gaps) & (log.t > states.t[idx] + 1e-9) & (log.t < states.t[idx + 1] - 1e-9)
    if inside.any():
        k = int(np.argmax(inside))
        raise IdentificationError(
            f"{log.source}: {int(inside.sum()):,} validation sample(s) fall in a gap of the states {states.source!r} "
            f"(first at t = {log.t[k]:.6g} s, between {states.t[idx[k]]:.6g} and {states.t[idx[k] + 1]:.6g} s); "
            "interpolating across it would invent q, dq, ddq: validate on the segments only (RobotLog.select)"
        )


def _interp_cols(t: np.ndarray, y: np.ndarray, tn: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(tn, t, y[:, j]) for j in range(y.shape[1])])
