"""Joint friction from ordinary motion: no constant-velocity runs needed (issue 17, item 4).

The paper's sequential method takes d_v, mu_C from single-joint constant-velocity runs
(:mod:`reflexarm.ident.friction.joint_friction`); a log of ordinary motion has none. Two estimators work on
such a log, both fitting ``tau_f(dq) = d_v dq + mu_C sgn(dq) [+ tau_off]`` per joint:

* ``"combined"``: the friction columns of the combined regression (eqs. (14)-(19), the paper's beta_I),
  estimated together with the base parameters by :func:`~reflexarm.ident.identify_dynamics`. Needs no
  rigid-body model: only the kinematics.
* ``"steady"``: a per-joint least-squares fit on the samples where the joint moves steadily (|ddq_j| below
  ``max_acceleration``, |dq_j| above ``min_speed``), with the rigid-body torque of a given ``model``
  removed. Only as good as that model's rigid-body torque.

Which to use (measured on the simulated UR-like 6-DoF arm of ``tests/ident_arms.py`` at 1 kHz, paper noise,
10 s of random 5-harmonic Fourier motion, no constant-velocity interval; ``tests/test_friction_from_motion.py``):

* with the nominal model off by +-10 % the steady fit is off by up to 55 % (Coulomb) and 150 % (viscous) on the
  gravity-loaded joints 2-3: the model's gravity error is read as friction. With the exact model it is within
  7 % on joints 2-5 (joint 1: up to 14 %).
* the combined columns need no model. Every joint peaking at 2 rad/s (4 seeds): Coulomb within 3.2 %, viscous
  within 8.3 % on joints 1-5. Peaking at 1.2 rad/s (3 seeds): Coulomb within 5 %, viscous up to 22 % (joint 2).
  A joint peaking at 0.5 rad/s: viscous +76 %. These are biases (the fit's std is ~1 %), so the std does not
  show them: slow motion gives a poorly separated d_v.
* at 100 Hz (the same logs, every 10th sample, the same noise per sample) the combined columns are worse:
  d_v off by up to 36 % (10 Hz cutoff; 60 s of log no better, so a bias, not noise) or 23 % (5 Hz cutoff) on
  joints 1-5: the differentiated, less filtered velocity noise enters the inertial columns.
* joint 6 of that arm is never within 10 %: its plant friction (MuJoCo's soft frictionloss constraint on a
  2e-4 kg m^2 link) reaches mu_C only above ~0.5 rad/s, which is not the Coulomb + viscous law.

So the default is ``"combined"``; ``"steady"`` is for a model already identified (``--model``).

Rows with |dq_j| < ``min_speed`` are left out of joint j's fit (both methods): there the sign of the
measured velocity is noise, and real (and MuJoCo's soft-constraint) friction is not Coulomb + viscous near
zero speed. A joint whose moving samples are too few, or whose speed range is too narrow to tell viscous
from Coulomb friction, gets no friction (NaN, :attr:`FrictionParameters.missing`) with the reason in
:attr:`MotionFriction.not_identified`; the sequential method then estimates it with the base parameters.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.identify import identify_dynamics
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.friction.parameters import FrictionParameters, check_friction_against_robot, format_joints
from reflexarm.logs._measured_torque import _rhs
from reflexarm.logs.plausibility import check_log_against_robot
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DEFAULT_MAX_ACCELERATION",
    "DEFAULT_MIN_SPEED",
    "FRICTION_METHODS",
    "MotionFriction",
    "identify_friction_from_motion",
]

#: The estimators of this module (see the module docstring); the first is the default.
FRICTION_METHODS = ("combined", "steady")
#: Rows with |dq_j| below this are left out of joint j's fit [rad/s]: the paper's velocity noise level
#: (0.055 rad/s) is where the measured sign becomes a coin flip; measured on the simulated arm, 0.055 and
#: 0.1 give the same errors within 2-5 %, 0 doubles them (Coulomb -10..-30 %).
DEFAULT_MIN_SPEED = 0.055
#: "Steady" for the steady fit: |ddq_j| below this [rad/s^2]. The inertial torque error of a +-10 % model
#: at 2 rad/s^2 is a few 0.01 Nm on the UR-like arm, well below its friction.
DEFAULT_MAX_ACCELERATION = 2.0
#: A joint is identified only with at least this many moving samples in each direction.
MIN_SAMPLES_PER_DIRECTION = 200
#: ... and a speed range (95th percentile of |dq_j| over its moving rows) of at least this many times
#: ``min_speed``: below, the viscous column d_v dq is nearly the Coulomb column mu_C sgn(dq) scaled.
MIN_SPEED_SPAN = 4.0


@dataclass(frozen=True)
class MotionFriction:
    """Friction identified from ordinary motion.

    Attributes:
        method: ``"combined"`` or ``"steady"``.
        friction: d_v [Nms/rad], mu_C [Nm] (and offsets) per joint; NaN for the joints in ``not_identified``.
        std: standard errors of ``friction`` (same layout).
        samples: rows used per joint (n,).
        speed_range: 95th percentile of |dq_j| over the rows used [rad/s] (n,).
        not_identified: 0-based joint -> why it got no friction.
        notes: what was done, for the result file.
    """

    method: str
    friction: FrictionParameters
    std: FrictionParameters
    samples: np.ndarray
    speed_range: np.ndarray
    not_identified: dict[int, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def describe(self, joint_names: Sequence[str] | None = None) -> str:
        """One line naming the method and the joints left out."""
        how = {
            "combined": "the friction columns of the combined regression (estimated with the base parameters)",
            "steady": "a fit on the steadily moving samples with the model's rigid-body torque removed",
        }[self.method]
        text = f"friction from ordinary motion by method '{self.method}': {how}"
        if self.not_identified:
            text += "; not identified: " + "; ".join(
                f"joint {format_joints([j], joint_names)}: {why}" for j, why in sorted(self.not_identified.items())
            )
        return text


def identify_friction_from_motion(
    robot: RobotModel,
    log: RobotLog | Sequence[RobotLog],
    *,
    method: str = "combined",
    model: RobotModel | None = None,
    min_speed: float = DEFAULT_MIN_SPEED,
    max_acceleration: float = DEFAULT_MAX_ACCELERATION,
    offset: bool = False,
    filter_cutoff_hz: float | None = None,
) -> MotionFriction:
    """Coulomb + viscous friction per joint from logs of ordinary motion (see the module docstring).

    Args:
        robot: the arm (kinematics; for ``"steady"`` also its rigid-body model unless ``model`` is given).
        log: preprocessed logs (with ``ddq``, :func:`~reflexarm.ident.preprocess_log`).
        method: ``"combined"`` or ``"steady"``.
        model: ``"steady"``: the model whose rigid-body torque (and armature, springs) is removed (default
            ``robot``); ignored by ``"combined"``.
        min_speed: rows with |dq_j| below this are left out of joint j's fit [rad/s].
        max_acceleration: ``"steady"``: rows with |ddq_j| above this are left out [rad/s^2].
        offset: fit a constant torque per joint too.
        filter_cutoff_hz: the cutoff the logs were filtered with (passed to the combined regression).

    Raises:
        IdentificationError: unknown method, a log without ddq, joint count mismatch, no joint moving enough.
        ImplausibleDataError: a log far outside the robot's limits (as :func:`~reflexarm.ident.identify_dynamics`).
    """
    if method not in FRICTION_METHODS:
        raise IdentificationError(f"unknown friction method {method!r}; choose one of: {', '.join(FRICTION_METHODS)}")
    logs = [log] if isinstance(log, RobotLog) else list(log)
    if not logs:
        raise IdentificationError("no log given")
    for lg in logs:
        if lg.n != robot.n:
            raise IdentificationError(f"{lg.source}: log has {lg.n} joints; robot {robot.name!r} has {robot.n}")
        if lg.ddq is None:
            raise IdentificationError(f"{lg.source}: log has no ddq; run reflexarm.ident.preprocess_log first")
        check_log_against_robot(lg, robot)  # as identify_dynamics: far beyond the limits is a bad log, not friction
    dq = np.concatenate([lg.dq for lg in logs])
    moving = np.abs(dq) >= min_speed
    samples = moving.sum(axis=0)
    speed_range = np.array([np.percentile(np.abs(dq[moving[:, j], j]), 95) if samples[j] else 0.0
                            for j in range(robot.n)])  # fmt: skip
    not_identified = _joints_not_moving_enough(dq, moving, speed_range, min_speed)
    if len(not_identified) == robot.n:
        raise IdentificationError(
            "no joint moves enough for friction from motion: "
            + "; ".join(f"joint {j + 1}: {why}" for j, why in not_identified.items())
        )
    if method == "combined":
        friction, std, notes = _combined(robot, logs, min_speed, offset, filter_cutoff_hz)
    else:
        friction, std, notes = _steady(model if model is not None else robot, logs, min_speed, max_acceleration, offset)
    keep = [j for j in range(robot.n) if j not in not_identified]
    if method == "steady":
        check_friction_against_robot(friction.restricted_to(keep), robot, joints=keep, std=std,
                                     source="friction from motion (steady)", stacklevel=2)  # fmt: skip
    return MotionFriction(
        method=method,
        friction=friction.restricted_to(keep),
        std=std,
        samples=samples,
        speed_range=speed_range,
        not_identified=not_identified,
        notes=tuple(notes),
    )


def _joints_not_moving_enough(
    dq: np.ndarray, moving: np.ndarray, speed_range: np.ndarray, min_speed: float
) -> dict[int, str]:
    out = {}
    for j in range(dq.shape[1]):
        pos = int(np.sum(moving[:, j] & (dq[:, j] > 0)))
        neg = int(np.sum(moving[:, j] & (dq[:, j] < 0)))
        if min(pos, neg) < MIN_SAMPLES_PER_DIRECTION:
            out[j] = (
                f"{pos} samples moving in + and {neg} in - direction above {min_speed:g} rad/s "
                f"(at least {MIN_SAMPLES_PER_DIRECTION} each needed)"
            )
        elif speed_range[j] < MIN_SPEED_SPAN * min_speed:
            out[j] = (
                f"speeds up to {speed_range[j]:.3g} rad/s (95th percentile) only: viscous and Coulomb friction cannot "
                f"be told apart below {MIN_SPEED_SPAN:g} x min_speed = {MIN_SPEED_SPAN * min_speed:.3g} rad/s"
            )
    return out


def _combined(
    robot: RobotModel, logs: list[RobotLog], min_speed: float, offset: bool, cutoff: float | None
) -> tuple[FrictionParameters, FrictionParameters, list[str]]:
    """The friction columns of the combined regression and their standard errors."""
    with warnings.catch_warnings():
        # the base parameters are a by-product here: their conditioning warnings are not about friction
        warnings.filterwarnings("ignore", module=r"reflexarm\.ident\.estimation")
        res = identify_dynamics(robot, logs, method="combined", offset=offset, min_speed=min_speed,
                                filter_cutoff_hz=cutoff)  # fmt: skip
    n, nb = robot.n, res.base.n_base
    std = FrictionParameters(res.beta_std[nb : nb + n], res.beta_std[nb + n : nb + 2 * n],
                             res.beta_std[nb + 2 * n : nb + 3 * n] if offset else None)  # fmt: skip
    notes = [
        f"combined regression: {nb} base parameters + {2 * n} friction parameters"
        + (f" + {n} offsets" if offset else "")
        + f" from {res.n_samples:,} samples, rows with |dq_j| < {min_speed:g} rad/s left out; condition number "
        f"{res.condition_number:.3g}"
    ]
    return res.friction, std, notes


def _steady(
    model: RobotModel, logs: list[RobotLog], min_speed: float, max_acceleration: float, offset: bool
) -> tuple[FrictionParameters, FrictionParameters, list[str]]:
    """Per-joint fit on the steady rows of ``tau - rigid-body torque of model``."""
    n = model.n
    reg = BatchRegressor(model)
    known = KnownJointTerms.from_robot(model)
    pi = model.inertial_parameters()
    f_parts, dq_parts, ddq_parts = [], [], []
    for lg in logs:
        assert lg.ddq is not None  # checked by the caller
        tau_rb = np.concatenate([Y @ pi for _, Y in reg.iter_chunks(lg.q, lg.dq, lg.ddq)])
        f_parts.append(_rhs(model, lg) - tau_rb - known.compute_torque(lg.q, lg.ddq))
        dq_parts.append(lg.dq)
        ddq_parts.append(lg.ddq)
    f, dq, ddq = np.concatenate(f_parts), np.concatenate(dq_parts), np.concatenate(ddq_parts)
    k = 3 if offset else 2
    x = np.full((k, n), np.nan)
    s = np.full((k, n), np.nan)
    used = []
    for j in range(n):
        rows = (np.abs(dq[:, j]) >= min_speed) & (np.abs(ddq[:, j]) <= max_acceleration)
        used.append(int(rows.sum()))
        if rows.sum() <= k:
            continue
        v = dq[rows, j]
        A = np.column_stack([v, np.sign(v)] + ([np.ones_like(v)] if offset else []))
        sol, *_ = np.linalg.lstsq(A, f[rows, j], rcond=None)
        r = f[rows, j] - A @ sol
        s2 = float(r @ r) / max(v.size - k, 1)
        x[:, j] = sol
        s[:, j] = np.sqrt(np.maximum(s2 * np.diag(np.linalg.pinv(A.T @ A)), 0.0))
    if not np.any(np.isfinite(x[0])):
        raise IdentificationError(
            f"no steady sample (|dq_j| >= {min_speed:g} rad/s, |ddq_j| <= {max_acceleration:g} rad/s^2) of any joint"
        )
    fr = FrictionParameters(x[0], x[1], x[2] if offset else None)
    std = FrictionParameters(s[0], s[1], s[2] if offset else None)
    notes = [
        f"steady fit: rigid-body torque of {model.name!r} removed; rows with |dq_j| >= {min_speed:g} rad/s and "
        f"|ddq_j| <= {max_acceleration:g} rad/s^2: " + ", ".join(f"{u:,}" for u in used) + " per joint"
    ]
    return fr, std, notes
