"""Unit checks of a log against its robot: positions that disagree with velocities, degrees on joints
without a range, torques on another scale than the robot's model.

The range check of :mod:`reflexarm.logs.plausibility` catches a revolute joint logged in degrees (its
positions leave the range); a continuous joint has no range, and a torque in mNm needs an effort limit.
Two checks that need neither, applied with the range check by
:func:`~reflexarm.logs.plausibility.check_log_against_robot`:

* **velocity / position consistency** (every joint): over windows of :data:`WINDOW` seconds, the change
  of q against the integral of dq. Where a joint moves measurably (the integral above
  :data:`MIN_MOTION` rad in at least :data:`MIN_WINDOWS` windows, the two correlated above
  :data:`MIN_CORRELATION`), their ratio (the median over the windows) must lie within
  :data:`RATIO_RANGE`: 57.3 is q in degrees beside dq in rad/s, 1/57.3 dq in degrees.
* **torque plausibility** (joints without a position range, and the torque's scale): the robot's
  own model (rigid body and the file's friction) predicts the measured torque from q, dq and ddq (from
  the log, else differentiated over the windows). Continuous joints read as degrees must not explain the
  torque :data:`DEGREE_GAIN` times better than read as radians; and where the model's torque is
  substantial, the measured torque's least-squares scale against it must lie within
  :data:`TORQUE_SCALE_RANGE` (1000 is a torque in mNm, a current instead of a torque, a wrong gain).

Each refusal is an :class:`~reflexarm.errors.ImplausibleDataError` naming the log, the joint (column)
and the numbers, with the likely cause.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from reflexarm.errors import ImplausibleDataError
from reflexarm.logs.bounds import BadSample

if TYPE_CHECKING:
    from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DEGREE_GAIN",
    "MIN_CORRELATION",
    "MIN_MOTION",
    "MIN_WINDOWS",
    "RATIO_RANGE",
    "TORQUE_SCALE_RANGE",
    "WINDOW",
    "check_units",
]

#: Window of the consistency check [s] (long enough to average encoder and velocity noise).
WINDOW = 0.05
#: A window counts as motion when the integral of dq over it exceeds this [rad].
MIN_MOTION = 1e-3
#: Windows of motion needed to judge a joint.
MIN_WINDOWS = 10
#: Correlation of delta q and the integral of dq needed to judge (below it q and dq are not comparable).
MIN_CORRELATION = 0.9
#: delta q / integral of dq must lie in this range [-]: a gear ratio or unit error is far outside.
RATIO_RANGE = (0.5, 2.0)
#: Joints without a range are refused as degrees if read so they explain the torque this many times
#: better (RMS of the model's error) than read as radians.
DEGREE_GAIN = 2.0
#: The measured torque's scale against the model's torque must lie in this range [-].
TORQUE_SCALE_RANGE = (0.2, 5.0)
#: Samples (evenly spread) on which the model's torque is evaluated.
_MODEL_SAMPLES = 2000
_DEG = np.pi / 180.0


def _windows(t: np.ndarray) -> np.ndarray:
    """Start indices of consecutive windows of about :data:`WINDOW` s (the last sample ends the last)."""
    step = float(np.median(np.diff(t)))
    k = max(int(round(WINDOW / step)), 1)
    return np.arange(0, t.size, k)


def _consistency(t: np.ndarray, q: np.ndarray, dq: np.ndarray) -> list[tuple[int, float]]:
    """(joint, ratio) for every judged joint whose delta q / integral of dq lies outside :data:`RATIO_RANGE`."""
    edges = _windows(t)
    if edges.size < MIN_WINDOWS + 1:
        return []
    integral = np.r_[np.zeros((1, q.shape[1])), np.cumsum(0.5 * (dq[1:] + dq[:-1]) * np.diff(t)[:, None], axis=0)]
    return judge_consistency(np.diff(q[edges], axis=0), np.diff(integral[edges], axis=0))


def judge_consistency(moved: np.ndarray, expected: np.ndarray) -> list[tuple[int, float]]:
    """:func:`_consistency` from the windows' delta q (``moved``) and integrals of dq (``expected``), (windows, n):
    a log read in blocks (:mod:`reflexarm.logs.blocks`) sums them block by block."""
    bad = []
    for j in range(moved.shape[1]):
        a, b = moved[:, j], expected[:, j]
        use = np.abs(b) > MIN_MOTION
        if use.sum() < MIN_WINDOWS:
            continue
        a, b = a[use], b[use]
        if np.std(a) == 0 or np.std(b) == 0:
            continue
        if abs(float(np.corrcoef(a, b)[0, 1])) < MIN_CORRELATION:
            continue
        ratio = float(np.median(a / b))
        if not RATIO_RANGE[0] <= abs(ratio) <= RATIO_RANGE[1]:
            bad.append((j, ratio))
    return bad


def _cause(ratio: float) -> str:
    r = abs(ratio)
    if 0.8 / _DEG <= r <= 1.25 / _DEG:
        return "positions in degrees, velocities in rad/s?"
    if 0.8 * _DEG <= r <= 1.25 * _DEG:
        return "velocities in degrees/s, positions in rad?"
    return "the columns of different joints, or a gear ratio or unit on one of them?"


def _model_torque(robot: RobotModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    return np.array([robot.compute_motor_torque(q[k], dq[k], ddq[k]) for k in range(q.shape[0])])


def _samples(t: np.ndarray, dq: np.ndarray, ddq: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(sample indices, ddq there): at most :data:`_MODEL_SAMPLES` rows, ddq from the log or a window's
    central difference of dq."""
    rows = np.unique(np.linspace(0, t.size - 1, min(t.size, _MODEL_SAMPLES)).round().astype(int))
    if ddq is not None:
        return rows, ddq[rows]
    k = max(int(round(0.5 * WINDOW / float(np.median(np.diff(t))))), 1)
    lo, hi = np.maximum(rows - k, 0), np.minimum(rows + k, t.size - 1)
    span = (t[hi] - t[lo])[:, None]
    return rows, np.where(span > 0, (dq[hi] - dq[lo]) / np.where(span > 0, span, 1.0), 0.0)


def check_units(
    source: str,
    t: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    tau: np.ndarray,
    robot: RobotModel,
    ddq: np.ndarray | None = None,
) -> None:
    """Raise :class:`ImplausibleDataError` for a unit error the module docstring describes."""
    refuse_inconsistent(source, robot, float(t[0]), _consistency(t, q, dq))
    rows, acc = _samples(t, dq, ddq)
    check_model_samples(source, robot, float(t[rows[0]]), q[rows], dq[rows], tau[rows], acc)


def refuse_inconsistent(source: str, robot: RobotModel, t0: float, bad: list[tuple[int, float]]) -> None:
    """Raise for the first joint of ``bad`` (:func:`judge_consistency`), if any."""
    for j, ratio in bad:
        sample = BadSample(source, 0, t0, f"q_{j + 1}", ratio, 1.0)
        raise ImplausibleDataError(
            f"{source}: q_{j + 1} ({robot.joint_names[j]}) changes {abs(ratio):.4g} times as much as the integral "
            f"of dq_{j + 1} over {WINDOW:g} s windows (expected 1; {_cause(ratio)}): convert the column to rad and "
            "rad/s (or scale it: --columns q=NAME*0.0174533 for degrees)",
            (sample,),
        )


def check_model_samples(
    source: str, robot: RobotModel, t0: float, Q: np.ndarray, DQ: np.ndarray, TAU: np.ndarray, acc: np.ndarray
) -> None:
    """The model checks (degrees on continuous joints, the torque's scale) on the samples of :func:`_samples`."""
    model = _model_torque(robot, Q, DQ, acc)
    _check_degrees(source, robot, Q, DQ, acc, TAU, model, t0)
    _check_torque_scale(source, robot, TAU, model, t0)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def _check_degrees(
    source: str,
    robot: RobotModel,
    q: np.ndarray,
    dq: np.ndarray,
    ddq: np.ndarray,
    tau: np.ndarray,
    model: np.ndarray,
    t0: float,
) -> None:
    lo, hi = robot.lower_limit, robot.upper_limit
    rangeless = ~(np.isfinite(lo) & np.isfinite(hi) & (hi > lo) & (hi - lo < 1e30))
    if not rangeless.any():
        return
    scale = np.where(rangeless, _DEG, 1.0)
    as_degrees = _model_torque(robot, q * scale, dq * scale, ddq * scale)
    err_rad, err_deg = _rms(tau - model), _rms(tau - as_degrees)
    if err_deg * DEGREE_GAIN < err_rad:
        joints = [j for j in range(robot.n) if rangeless[j]]
        names = ", ".join(f"q_{j + 1} ({robot.joint_names[j]})" for j in joints)
        raise ImplausibleDataError(
            f"{source}: the continuous joint(s) {names} look logged in degrees: the robot's model explains the "
            f"measured torque with an RMS error of {err_rad:.4g} Nm reading them as radians, {err_deg:.4g} Nm reading "
            "them as degrees; convert q and dq of those joints to rad and rad/s (or scale them: --columns "
            "q=NAME*0.0174533)",
            tuple(BadSample(source, 0, t0, f"q_{j + 1}", float(q[0, j]), 0.0) for j in joints),
        )


def _check_torque_scale(source: str, robot: RobotModel, tau: np.ndarray, model: np.ndarray, t0: float) -> None:
    effort = robot.effort_limit
    floor = 0.01 * float(np.max(np.where(np.isfinite(effort) & (effort < 1e30), effort, 0.0), initial=0.0))
    if _rms(model) <= max(floor, 0.1):
        return  # the model's torque is too small to compare a scale against
    scale = float(np.sum(tau * model) / np.sum(model * model))
    explained = 1.0 - _rms(tau - scale * model) ** 2 / max(_rms(tau - tau.mean(axis=0)) ** 2, 1e-300)
    if explained < 0.5 or TORQUE_SCALE_RANGE[0] <= abs(scale) <= TORQUE_SCALE_RANGE[1]:
        return
    cause = "mNm instead of Nm?" if 500 <= abs(scale) <= 2000 else "a current instead of a torque, or a wrong gain?"
    raise ImplausibleDataError(
        f"{source}: the measured torque is {scale:.4g} times the robot model's torque along the log (least squares, "
        f"{100 * explained:.0f} % explained; expected about 1): {cause} Give torques in Nm (scale a column: --columns "
        "tau=NAME*0.001; currents: --torque-from current --gains ...)",
        (BadSample(source, 0, t0, "tau", scale, 1.0),),
    )
