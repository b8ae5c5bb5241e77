"""A payload at the tool: its mass and COM (optionally inertia) from a log, and a change of load found in one.

With the arm's model known (a robot file, or one identified by ``identify dynamics``), what the model does
not explain of the measured torque,

    r = tau_m (+ J^T F_wrist) - (Y(q, dq, ddq) pi + tau_f(dq) + I_a ddq + K_s (q - q_s)),

is, for a rigid load fixed to the last link, linear in that load's 10 inertial parameters:
``r = Y_n(q, dq, ddq) delta_pi_n`` with Y_n the last link's 10 columns of the regressor
(:class:`~reflexarm.ident.estimation.regressor.BatchRegressor`). With the other links known, these columns
alone are independent for motion that moves the arm (the regrouping of the base parameters involves the
previous link's columns, which are fixed here).

* :func:`identify_payload` solves the small least-squares problem: by default a point mass (m and the first
  moment m c, 4 unknowns; its inertia about the joint m (|c|^2 E - c c^T) is added by a few fixed-point
  passes), or with ``inertia=True`` all 10 parameters. The result is in the tool frame (the robot's
  ``ee_frame``): mass [kg], COM [m], inertia about the COM [kg m^2].
* :func:`detect_payload_change` looks for a time where the residual's payload changes: for each candidate
  split the point mass is fitted before and after (cumulative normal equations: one pass), the split with
  the smallest residual wins, and a change is flagged when the masses differ by more than ``min_mass`` and
  by more than ``sigmas`` standard errors. It reports the time and the mass that explains the change.
* :func:`with_payload` adds a payload to a model (the last link's parameters); :func:`write_model_with_payload`
  to an identified-model file.

Rows where |dq_j| < ``min_speed`` are left out of joint j's equations: there the model's Coulomb friction
has an undetermined sign (the same rule as :func:`~reflexarm.ident.identify_dynamics`'s ``min_speed``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.friction.parameters import FrictionParameters
from reflexarm.logs._measured_torque import _rhs
from reflexarm.logs.plausibility import check_log_against_robot
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "DEFAULT_MIN_MASS",
    "DEFAULT_MIN_SPEED",
    "Payload",
    "PayloadChange",
    "detect_payload_change",
    "identify_payload",
    "with_payload",
    "write_model_with_payload",
]

#: Rows with |dq_j| below this are left out of joint j's equations [rad/s] (the paper's velocity noise).
DEFAULT_MIN_SPEED = 0.055
#: Smallest change of load flagged [kg]. A 0.2 kg error at 0.5 m reach is ~1 Nm of shoulder torque: the
#: order of a good identified model's torque error, below which a "change" is not actionable.
DEFAULT_MIN_MASS = 0.2
#: A change must also exceed this many standard errors of the mass difference.
DEFAULT_SIGMAS = 10.0
#: Shortest segment before or after a change considered [s]: the point mass needs motion on both sides.
DEFAULT_MIN_SEGMENT = 2.0
#: Fixed-point passes adding the point mass's own inertia (converges to 1e-6 relative in 2-3 on arms with
#: a tool inertia far below m |c|^2 ... or comparable: the inertia term is a small share of the torque).
_POINT_MASS_PASSES = 4


@dataclass(frozen=True)
class Payload:
    """A rigid load at the tool.

    Attributes:
        mass: m [kg]; mass_std its standard error.
        com: centre of mass in the tool frame (3,) [m]; com_std (3,).
        inertia: about the COM, in the tool frame (3, 3) [kg m^2]; a point mass's zeros unless identified.
        frame: the tool frame's name.
        parameters: the last link's delta_pi (10,) in Pinocchio's order, about the last joint's frame.
        residual_rms_before, residual_rms_after: per joint RMS of the residual without / with the payload [Nm].
        n_samples: samples used; method: ``"point mass"`` or ``"10 parameters"``.
    """

    mass: float
    mass_std: float
    com: np.ndarray
    com_std: np.ndarray
    inertia: np.ndarray
    frame: str
    parameters: np.ndarray
    residual_rms_before: np.ndarray
    residual_rms_after: np.ndarray
    n_samples: int
    method: str

    def describe(self) -> str:
        c = ", ".join(f"{1000 * x:+.1f}" for x in self.com)
        cs = ", ".join(f"{1000 * x:.1f}" for x in self.com_std)
        return (
            f"payload ({self.method}) at '{self.frame}': mass {self.mass:.3f} +- {self.mass_std:.3f} kg, COM "
            f"({c}) +- ({cs}) mm; residual RMS {np.sqrt(np.mean(self.residual_rms_before**2)):.3f} -> "
            f"{np.sqrt(np.mean(self.residual_rms_after**2)):.3f} Nm over {self.n_samples:,} samples"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "frame": self.frame,
            "method": self.method,
            "mass": self.mass,
            "mass_std": self.mass_std,
            "com": self.com.tolist(),
            "com_std": self.com_std.tolist(),
            "inertia_about_com": self.inertia.tolist(),
            "last_link_parameters": self.parameters.tolist(),
            "residual_rms_before": self.residual_rms_before.tolist(),
            "residual_rms_after": self.residual_rms_after.tolist(),
            "n_samples": self.n_samples,
        }


@dataclass(frozen=True)
class PayloadChange:
    """The result of :func:`detect_payload_change`.

    Attributes:
        changed: a change was flagged.
        time: time of the best split [s] (the log's clock); t_index its sample.
        mass_before, mass_after: point masses fitted on either side [kg]; mass_change their difference and
            mass_change_std its standard error.
        com_change: COM in the tool frame of the mass that explains the change [m] (NaN if no change).
        reason: one line saying why it was or was not flagged.
    """

    changed: bool
    time: float
    t_index: int
    mass_before: float
    mass_after: float
    mass_change: float
    mass_change_std: float
    com_change: np.ndarray
    reason: str

    def to_dict(self) -> dict[str, object]:
        return {
            "changed": self.changed,
            "time": self.time,
            "mass_before": self.mass_before,
            "mass_after": self.mass_after,
            "mass_change": self.mass_change,
            "mass_change_std": self.mass_change_std,
            "com_change": self.com_change.tolist(),
            "reason": self.reason,
        }


class _Residual:
    """Rows of the payload problem: the last link's regressor columns and the model's residual."""

    def __init__(self, robot: RobotModel, logs: Sequence[RobotLog], model: RobotModel | None, min_speed: float):
        model = robot if model is None else model
        if model.n != robot.n or list(model.joint_names) != list(robot.joint_names):
            raise IdentificationError(
                f"model {model.name!r} has joints {model.joint_names}; robot has {robot.joint_names}"
            )
        frame = robot.ee_frame
        fid = robot.frame_id(frame)
        fr = robot.pin_model.frames[fid]
        if int(fr.parentJoint) != robot.n:
            raise IdentificationError(
                f"tool frame {frame!r} is not on the last link (its joint is "
                f"{robot.pin_model.names[fr.parentJoint]!r}); "
                "a payload is identified on the last link"
            )
        self.frame, self.placement = frame, fr.placement
        n = robot.n
        reg = BatchRegressor(model)
        pi = model.inertial_parameters()
        known = KnownJointTerms.from_robot(model)
        friction = FrictionParameters.from_model(model.friction)
        Ys, bs, ts = [], [], []
        for lg in logs:
            if lg.n != n:
                raise IdentificationError(f"{lg.source}: log has {lg.n} joints; robot {robot.name!r} has {n}")
            if lg.ddq is None:
                raise IdentificationError(f"{lg.source}: log has no ddq; run reflexarm.ident.preprocess_log first")
            check_log_against_robot(lg, robot)  # far beyond the limits: a bad log, not a payload
            r = _rhs(model, lg) - friction.compute_torque(lg.dq) - known.compute_torque(lg.q, lg.ddq)
            for sl, Y in reg.iter_chunks(lg.q, lg.dq, lg.ddq):
                r[sl] -= Y @ pi
                Ys.append(Y[:, :, 10 * (n - 1) :].copy())
            keep = np.abs(lg.dq) >= min_speed
            r[~keep] = 0.0
            bs.append(r)
            ts.append(lg.t)
        self.Y = np.concatenate(Ys)  # (N, n, 10)
        self.b = np.concatenate(bs)  # (N, n)
        self.keep = np.concatenate([np.abs(lg.dq) >= min_speed for lg in logs])
        self.Y[~self.keep] = 0.0
        self.t = np.concatenate(ts)

    def tool_com(self, com_joint: np.ndarray) -> np.ndarray:
        """A point in the last joint's frame, in the tool frame."""
        return np.asarray(self.placement.actInv(pin.SE3(np.eye(3), com_joint)).translation)


def _point_inertia(m: float, h: np.ndarray) -> np.ndarray:
    """(Ixx, Ixy, Iyy, Ixz, Iyz, Izz) about the origin of a point mass m with first moment h."""
    if m <= 0:
        return np.zeros(6)
    c = h / m
    S = m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([S[0, 0], S[0, 1], S[1, 1], S[0, 2], S[1, 2], S[2, 2]])


def _solve(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares with covariance s^2 (A^T A)^-1; returns x, cov, residual sum of squares."""
    G = A.T @ A
    x = np.linalg.solve(G, A.T @ b)
    r = b - A @ x
    ss = float(r @ r)
    dof = max(b.size - x.size, 1)
    return x, ss / dof * np.linalg.inv(G), ss


def identify_payload(
    robot: RobotModel,
    log: RobotLog | Sequence[RobotLog],
    *,
    model: RobotModel | None = None,
    inertia: bool = False,
    min_speed: float = DEFAULT_MIN_SPEED,
) -> Payload:
    """Mass and COM (and with ``inertia`` the inertia) of a load at the tool, from preprocessed logs.

    Args:
        robot: the arm (kinematics, tool frame = its ``ee_frame``, on the last link).
        log: preprocessed logs (with ``ddq``).
        model: the arm's model without the payload (inertias, friction, armature; default ``robot``).
        inertia: identify all 10 parameters (else a point mass: 4).
        min_speed: rows with |dq_j| below this are left out of joint j's equations [rad/s].

    Raises:
        IdentificationError: a log without ddq, joints that do not match, a tool frame not on the last link,
            or data that do not determine the payload (rank deficient: the arm did not move enough).
    """
    logs = [log] if isinstance(log, RobotLog) else list(log)
    if not logs:
        raise IdentificationError("no log given")
    res = _Residual(robot, logs, model, min_speed)
    k = 10 if inertia else 4
    A = res.Y[:, :, :k].reshape(-1, k)
    b = res.b.reshape(-1)
    rank = np.linalg.matrix_rank(A.T @ A)
    if rank < k:
        raise IdentificationError(
            f"the log does not determine the payload: rank {rank} of {k} unknowns in {res.Y.shape[0]:,} samples; "
            "log motion that moves the arm through several postures"
        )
    x, cov, _ = _solve(A, b)
    if not inertia:  # point mass: move its own inertia about the joint to the known side, refit
        for _ in range(_POINT_MASS_PASSES):
            Iq = _point_inertia(x[0], x[1:4])
            x, cov, _ = _solve(A, b - res.Y[:, :, 4:].reshape(-1, 6) @ Iq)
        delta = np.r_[x, _point_inertia(x[0], x[1:4])]
    else:
        delta = x
    m = float(delta[0])
    com_joint = delta[1:4] / m if m != 0 else np.zeros(3)
    # first-order std of c = h / m
    Jc = np.hstack([-com_joint[:, None] / m, np.eye(3) / m]) if m != 0 else np.zeros((3, 4))
    com_std = np.sqrt(np.maximum(np.diag(Jc @ cov[:4, :4] @ Jc.T), 0.0))
    I_about_com = np.zeros((3, 3))
    if inertia:
        Ij = pin.Inertia.FromDynamicParameters(delta)
        R = res.placement.rotation
        I_about_com = R.T @ np.asarray(Ij.inertia) @ R
    after = res.b - np.einsum("knp,p->kn", res.Y, delta)
    rows = np.maximum(res.keep.sum(axis=0), 1)
    return Payload(
        mass=m,
        mass_std=float(np.sqrt(cov[0, 0])),
        com=res.tool_com(com_joint),
        com_std=com_std,
        inertia=I_about_com,
        frame=res.frame,
        parameters=delta,
        residual_rms_before=np.sqrt((res.b**2).sum(axis=0) / rows),
        residual_rms_after=np.sqrt((after**2).sum(axis=0) / rows),
        n_samples=int(res.Y.shape[0]),
        method="10 parameters" if inertia else "point mass",
    )


def detect_payload_change(
    robot: RobotModel,
    log: RobotLog,
    *,
    model: RobotModel | None = None,
    min_mass: float = DEFAULT_MIN_MASS,
    sigmas: float = DEFAULT_SIGMAS,
    min_segment: float = DEFAULT_MIN_SEGMENT,
    min_speed: float = DEFAULT_MIN_SPEED,
) -> PayloadChange:
    """Whether (and when) the load at the tool changed during ``log`` (a preprocessed log; see the module).

    Raises:
        IdentificationError: as :func:`identify_payload`; a log shorter than two ``min_segment``.
    """
    res = _Residual(robot, [log], model, min_speed)
    t = res.t
    if t[-1] - t[0] < 2 * min_segment:
        raise IdentificationError(
            f"{log.source}: {t[-1] - t[0]:.3g} s is too short to look for a change of load (two segments of at "
            f"least {min_segment:g} s are needed)"
        )
    A = res.Y[:, :, :4]  # (N, n, 4): point mass, its inertia left in the residual
    G = np.cumsum(np.einsum("kni,knj->kij", A, A), axis=0)
    g = np.cumsum(np.einsum("kni,kn->ki", A, res.b), axis=0)
    s = np.cumsum(np.einsum("kn,kn->k", res.b, res.b))
    candidates = np.flatnonzero((t - t[0] >= min_segment) & (t[-1] - t >= min_segment))
    candidates = candidates[:: max(1, candidates.size // 2000)]  # at most ~2000 splits: ms resolution is not needed

    def fit(Gs: np.ndarray, gs: np.ndarray, ss: float) -> tuple[np.ndarray, float]:
        x = np.linalg.lstsq(Gs, gs, rcond=None)[0]
        return x, ss - float(gs @ x)

    best = (np.inf, -1)
    for kc in candidates:
        k = int(kc)
        _, r1 = fit(G[k - 1], g[k - 1], s[k - 1])
        _, r2 = fit(G[-1] - G[k - 1], g[-1] - g[k - 1], s[-1] - s[k - 1])
        if r1 + r2 < best[0]:
            best = (r1 + r2, int(k))
    ss_split, k = best[0], int(best[1])
    x1, _ = fit(G[k - 1], g[k - 1], s[k - 1])
    G2 = G[-1] - G[k - 1]
    x2, _ = fit(G2, g[-1] - g[k - 1], s[-1] - s[k - 1])
    dof = max(int(res.keep.sum()) - 8, 1)
    s2 = ss_split / dof
    var_dm = s2 * (np.linalg.pinv(G[k - 1])[0, 0] + np.linalg.pinv(G2)[0, 0])
    dm = float(x2[0] - x1[0])
    dm_std = float(np.sqrt(max(var_dm, 0.0)))
    changed = abs(dm) > min_mass and abs(dm) > sigmas * dm_std
    dh = x2[1:4] - x1[1:4]
    com = res.tool_com(dh / dm) if changed else np.full(3, np.nan)
    if changed:
        reason = (
            f"the load changed at t = {t[k]:.3f} s: a mass of {dm:+.3f} kg (+- {dm_std:.3f}) at the tool explains the "
            f"residual after it (fitted {x1[0]:.3f} kg before, {x2[0]:.3f} kg after, relative to the model)"
        )
    else:
        reason = (
            f"no change of load: best split at t = {t[k]:.3f} s changes the mass by {dm:+.3f} +- {dm_std:.3f} kg "
            f"(flagged above {min_mass:g} kg and {sigmas:g} standard errors)"
        )
    return PayloadChange(changed, float(t[k]), k, float(x1[0]), float(x2[0]), dm, dm_std, com, reason)


def with_payload(model: RobotModel, payload: Payload) -> RobotModel:
    """``model`` with the payload added to its last link's inertial parameters."""
    pi = model.inertial_parameters().copy()
    pi[-10:] += payload.parameters
    return model.with_inertial_parameters(pi)


def write_model_with_payload(
    model_file: str | os.PathLike[str], payload: Payload, path: str | os.PathLike[str]
) -> Path:
    """A copy of an identified-model file (``identify dynamics``'s model.json) with ``payload`` added to the last
    link: its standard and base parameters (the base ones through the file's own map), the payload recorded
    under ``extra.payload``. :func:`~reflexarm.ident.load_identified_model` loads the copy.
    """
    from reflexarm.ident.export.model_file import read_identified_model

    result, doc = read_identified_model(model_file)
    pi = np.asarray(doc["standard_parameters"], dtype=float).copy()
    if pi.size != 10 * result.n:
        raise IdentificationError(
            f"{Path(model_file).name}: expected {10 * result.n} standard parameters; found {pi.size}"
        )
    pi[-10:] += payload.parameters
    physical = (
        None
        if result.physical_parameters is None
        else np.asarray(result.physical_parameters) + np.r_[np.zeros(10 * (result.n - 1)), payload.parameters]
    )
    updated = replace(result, beta_b=result.base.base_from_standard(pi), physical_parameters=physical)
    doc["identification"] = updated.to_dict()
    doc["standard_parameters"] = pi.tolist()
    doc.setdefault("extra", {})["payload"] = payload.to_dict()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1))
    return out
