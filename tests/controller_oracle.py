"""An independent tick of the controller in plain numpy/Pinocchio: the oracle of the C++ core and of Controller.

Written from the paper's equations (2), (4)-(6), (9)-(13) and the contract of
:class:`reflexarm.control.Controller` with whole-vector numpy operations, ``np.linalg.cholesky``/``eigh`` for the
modal damping and no code of the package's tick. ``ticks`` is the seeded run both sides see (with bad ticks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from reflexarm.control.contract import (
    MASS_NOT_POSITIVE_DEFINITE,
    MODEL_NON_FINITE,
    NON_FINITE,
    OBSERVER_INVALID,
    OUT_OF_BOUNDS,
    OUTPUT_NON_FINITE,
    SIG_DDQ_D,
    SIG_DQ,
    SIG_DQ_D,
    SIG_GRAVITY,
    SIG_MODEL,
    SIG_Q,
    SIG_Q_D,
    SIG_T,
    SIG_TAU_M,
    SIG_WRENCH,
    TIME_NOT_INCREASING,
)
from reflexarm.robots.robot_model import RobotModel

DT = 1e-3
N_TICKS = 300

#: Accepted ticks over which the core spreads one computation of the modal damping (at most): the contract of
#: ControllerParams.damping_update_period / Controller.kDampingParts (cpp/include/reflexarm/params.hpp).
DAMPING_TICKS = 4

BOUNDS = {
    "margin": 0.2,
    "velocity_factor": 10.0,
    "torque_factor": 3.0,
    "force": 2000.0,
    "moment": 200.0,
    "g_tol": 1.0,
    "acc": 1000.0,
    "velocity": 100.0,
    "torque": 1e4,
}  # fmt: skip  (InputBounds defaults)


@dataclass
class Oracle:
    """One control tick in plain numpy: eqs. (2), (4)-(6), (9)-(13) and the input contract."""

    robot: RobotModel
    stiffness: float = 300.0
    damping_ratio: float = 0.7
    observer_gain: float = 5.0
    detection_observer_gain: float | None = None
    threshold: float | None = 11.0
    reaction: str = "gravity"
    kappa_f: int = 0
    kappa_eps: int = 0
    kappa_ext: int = 0
    residual_limit: float = 30.0
    switch_time: float = 0.1
    damping_update_period: int = 10
    torque_rate_limit: float | None = None
    state: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        r, n = self.robot, self.robot.n
        self.n = n
        self.model = r.pin_model.copy()
        self.data = self.model.createData()
        self.model0 = r.pin_model.copy()
        self.model0.gravity.linear = np.zeros(3)
        self.data0 = self.model0.createData()
        self.gravity = self.model.gravity.linear.copy()
        self.g_norm = float(np.linalg.norm(self.gravity))
        lo, hi = r.lower_limit, r.upper_limit
        self.q_lo = np.where(np.isfinite(lo), lo - BOUNDS["margin"], -np.inf)
        self.q_hi = np.where(np.isfinite(hi), hi + BOUNDS["margin"], np.inf)
        vel = r.velocity_limit
        self.dq_max = np.where(np.isfinite(vel) & (vel > 0), BOUNDS["velocity_factor"] * vel, BOUNDS["velocity"])
        eff = r.effort_limit
        ok = np.isfinite(eff) & (eff > 0)
        self.tau_max = np.where(ok, eff, np.inf)
        self.tau_m_max = np.where(ok, BOUNDS["torque_factor"] * np.where(ok, eff, 1.0), BOUNDS["torque"])
        self.step_max = np.full(n, np.inf if self.torque_rate_limit is None else self.torque_rate_limit * DT)
        self.D = np.zeros((n, n))
        self.last_q = None
        self.prev_tau = None
        self.reacted = False
        self.detected = False
        self.eps_before = self.kappa_eps
        self.reset()

    def reset(self) -> None:
        if self.reacted and self.reaction == "compliant":
            self.kappa_eps = self.eps_before
        self.reacted = self.detected = False
        self.obs = [np.zeros((3, self.n)), np.zeros((3, self.n))]  # integral, p0, residual per observer
        self.started, self.last_t, self.invalid, self.countdown = False, None, False, 0
        self.pending: tuple[np.ndarray | None, int] | None = None  # (next D, accepted ticks until it is used)
        self.full = True
        self.eps_w = float(self.kappa_eps)

    def set_switches(self, kappa_eps: int) -> None:
        self.kappa_eps = kappa_eps
        if self.switch_time == 0.0:
            self.eps_w = float(kappa_eps)

    @property
    def gravity_mode(self) -> bool:
        return self.reacted and self.reaction == "gravity"

    @property
    def mode(self) -> str:
        if self.gravity_mode:
            return "gravity_compensation"
        if not self.kappa_eps:
            return "compliant"
        return "precise_ee_compliant" if self.kappa_ext else "precise_stiff"

    def r_det(self) -> np.ndarray:
        return self.obs[1 if self.detection_observer_gain is not None else 0][2]

    # ------------------------------------------------------------------ contract
    def check(self, t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d):
        """(code, signal, index, value, lo, hi) of the first broken bound, or None."""
        if not math.isfinite(t):
            return NON_FINITE, SIG_T, -1, t, -np.inf, np.inf
        if self.last_t is not None and not t > self.last_t:
            return TIME_NOT_INCREASING, SIG_T, -1, t, self.last_t, np.inf
        fm, mm = BOUNDS["force"], BOUNDS["moment"]
        wb = np.array([fm] * 3 + [mm] * 3)
        gn = float(np.sqrt(np.sum(gravity * gravity))) if np.all(np.isfinite(gravity)) else None
        g_lo, g_hi = max(self.g_norm - BOUNDS["g_tol"], 0.0), self.g_norm + BOUNDS["g_tol"]
        acc = np.full(self.n, BOUNDS["acc"])
        for sig, x, lo, hi in ((SIG_Q, q, self.q_lo, self.q_hi), (SIG_DQ, dq, -self.dq_max, self.dq_max),
                               (SIG_TAU_M, tau_m, -self.tau_m_max, self.tau_m_max),
                               (SIG_WRENCH, wrench, -wb, wb), (SIG_GRAVITY, gravity, None, None),
                               (SIG_Q_D, q_d, self.q_lo, self.q_hi),
                               (SIG_DQ_D, dq_d, -self.dq_max, self.dq_max),
                               (SIG_DDQ_D, ddq_d, -acc, acc)):  # fmt: skip
            if sig == SIG_GRAVITY:
                bad = np.flatnonzero(~np.isfinite(x))
                if bad.size:
                    return NON_FINITE, sig, int(bad[0]), x[bad[0]], -np.inf, np.inf
                if not g_lo <= gn <= g_hi:
                    return OUT_OF_BOUNDS, sig, -1, gn, g_lo, g_hi
                continue
            bad = np.flatnonzero(~np.isfinite(x) | (x < lo) | (x > hi))
            if bad.size:
                i = int(bad[0])
                code = NON_FINITE if not np.isfinite(x[i]) else OUT_OF_BOUNDS
                return code, sig, i, x[i], lo[i], hi[i]
        return None

    def modal_damping(self, M: np.ndarray) -> np.ndarray | None:
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            return None
        Li = np.linalg.inv(L)
        lam, U = np.linalg.eigh(Li @ np.diag(np.full(self.n, self.stiffness)) @ Li.T)
        LU = L @ U
        return LU @ np.diag(2.0 * self.damping_ratio * np.sqrt(np.maximum(lam, 0.0))) @ LU.T

    # ------------------------------------------------------------------ the tick
    def step(self, t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) -> dict:
        fault = self.check(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d)
        if fault is not None:
            return self.reject(fault)
        n, model = self.n, self.model
        model.gravity.linear = gravity  # a candidate until the tick is accepted
        g = pin.computeGeneralizedGravity(model, self.data, q) + self.robot.compute_spring_torque(q)
        C = pin.computeCoriolisMatrix(model, self.data, q, dq).copy()
        p = pin.rnea(self.model0, self.data0, q, np.zeros(n), dq).copy()
        ff = pin.rnea(self.model0, self.data0, q_d, np.zeros(n), ddq_d).copy()
        J = np.zeros((6, n))
        if self.kappa_ext:
            J = pin.computeFrameJacobian(model, self.data, q, self.robot.sensor_frame_id, pin.LOCAL).copy()
        eps_w = self.eps_w
        if eps_w != self.kappa_eps:
            inc = DT / self.switch_time
            eps_w = min(eps_w + inc, 1.0) if self.kappa_eps > eps_w else max(eps_w - inc, 0.0)
        # D from M(q) every damping_update_period accepted ticks, put in use min(DAMPING_TICKS, period) - 1 ticks
        # later (the core spreads the computation over that many ticks); whole on the first tick after a reset
        D: np.ndarray | None = self.D
        pending, full = self.pending, self.full
        if self.gravity_mode:
            pending = None
        elif self.countdown == 0:
            Mu = pin.crba(model, self.data, q)
            new_D = self.modal_damping(np.triu(Mu) + np.triu(Mu, 1).T)
            span = 1 if full else min(DAMPING_TICKS, self.damping_update_period)
            D, pending = (new_D, None) if span == 1 else (D, (new_D, span - 1))
            full = False
        elif pending is not None:
            pending = (pending[0], pending[1] - 1)
            if pending[1] == 0:
                D, pending = pending[0], None
        assert D is not None and all(np.all(np.isfinite(x)) for x in (g, C, p, ff, J))
        self.D, self.last_q, self.pending, self.full = D, q.copy(), pending, full
        h = DT if self.last_t is None else min(max(t - self.last_t, 0.5 * DT), 2.0 * DT)
        self.last_t = t
        if self.invalid:
            return self.reject((OBSERVER_INVALID, 0, -1, 0.0, 0.0, 0.0))
        if not self.started:
            for o in self.obs:
                o[0], o[1], o[2] = 0.0, p, 0.0
            self.started = True
        else:
            fr = self.robot.friction
            tau_f = fr.coulomb * np.clip(dq / fr.velocity_band, -1, 1) + fr.viscous * dq
            alpha = self.kappa_f * tau_f - J.T @ wrench
            base = tau_m - (g - C.T @ dq) - alpha  # tau_m - gamma - alpha, eqs. (4)-(6)
            gains = (self.observer_gain, self.detection_observer_gain)
            for o, k_o in zip(self.obs, gains, strict=True):
                if k_o is not None:
                    o[0] += h * (base + o[2])
                    o[2] = k_o * (p - o[1] - o[0])
        if not all(np.all(np.isfinite(o)) for o in self.obs):
            self.invalid = True
            return self.reject((OBSERVER_INVALID, 0, -1, 0.0, 0.0, 0.0))
        fr = self.robot.friction
        tau_f = fr.coulomb * np.clip(dq / fr.velocity_band, -1, 1) + fr.viscous * dq
        over = np.abs(self.r_det()) > (np.inf if self.threshold is None else self.threshold)
        if self.gravity_mode:
            tau = g
        else:
            r = np.clip(self.obs[0][2], -self.residual_limit, self.residual_limit)
            tau = self.stiffness * (q_d - q) + D @ (dq_d - dq) + g + C @ dq + ff + self.kappa_f * tau_f - eps_w * r
        bounded = self.bound(tau)
        self.model.gravity.linear, self.gravity = gravity, gravity.copy()
        self.eps_w = eps_w
        if not self.gravity_mode:
            self.countdown = (self.countdown or self.damping_update_period) - 1
        if over.any():
            self.detected = True
            if not self.reacted and self.reaction != "none":
                self.reacted = True
                if self.reaction == "compliant":
                    self.eps_before = self.kappa_eps
                    self.set_switches(0)
        return {"code": 0, "tau": bounded, "residual": self.r_det().copy(), "collision": self.detected,
                "collided": over, "saturated": bounded != tau, "mode": self.mode, "fault": None}  # fmt: skip

    def bound(self, tau: np.ndarray) -> np.ndarray:
        b = tau.copy()
        if self.prev_tau is not None:
            b = np.clip(b, self.prev_tau - self.step_max, self.prev_tau + self.step_max)
        b = np.clip(b, -self.tau_max, self.tau_max)
        self.prev_tau = b
        return b

    def reject(self, fault: tuple) -> dict:
        """Safe command: gravity compensation at the last accepted position, bounded; nothing else changes."""
        self.model.gravity.linear = self.gravity
        tau = np.zeros(self.n)
        if self.last_q is not None:
            g = pin.computeGeneralizedGravity(self.model, self.data, self.last_q)
            tau = g + self.robot.compute_spring_torque(self.last_q)
        bounded = self.bound(tau)
        collision = True if fault[0] == OBSERVER_INVALID else self.detected
        zeros = np.zeros(self.n, bool)
        return {"code": fault[0], "tau": bounded, "residual": self.r_det().copy(), "collision": collision,
                "collided": zeros, "saturated": bounded != tau, "mode": "fault", "fault": fault}  # fmt: skip


def core_controller(core: Any, robot: RobotModel, o: Oracle) -> Any:
    """The C++ controller with the oracle's settings (the model crosses as pin.Model.saveToString text)."""
    p = core.ControllerParams()
    p.stiffness, p.damping_ratio = np.array([o.stiffness]), np.array([o.damping_ratio])
    p.observer_gain = np.array([o.observer_gain])
    det = o.detection_observer_gain
    p.detection_observer_gain = np.zeros(0) if det is None else np.array([det])
    p.threshold = np.zeros(0) if o.threshold is None else np.array([o.threshold])
    p.reaction = o.reaction
    p.kappa_f, p.kappa_eps, p.kappa_ext = o.kappa_f, o.kappa_eps, o.kappa_ext
    p.residual_limit, p.switch_time, p.dt = o.residual_limit, o.switch_time, DT
    p.damping_update_period = o.damping_update_period
    fr = robot.friction
    p.friction_coulomb, p.friction_viscous = fr.coulomb.copy(), fr.viscous.copy()
    p.friction_velocity_band = fr.velocity_band
    p.sensor_frame_id = robot.sensor_frame_id
    if robot.has_springs:
        p.spring_stiffness, p.spring_reference = robot.spring_stiffness, robot.spring_reference
    if o.torque_rate_limit is not None:
        p.torque_rate_limit = np.array([o.torque_rate_limit])
    return core.Controller(robot.pin_model.saveToString(), p)


def ticks(robot, *, seed: int = 0, push: float = 0.0, faults: bool = True):
    """(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) along a seeded random reference, with bad ticks."""
    rng = np.random.default_rng(seed)
    n = robot.n
    phase = rng.uniform(0, 2 * np.pi, n)
    t = 0.0
    for k in range(N_TICKS):
        t += DT
        s = 2.0 * t + phase
        q_d = robot.home + 0.3 * np.sin(s) + rng.uniform(-0.01, 0.01, n)
        dq_d, ddq_d = 0.6 * np.cos(s) + rng.uniform(-0.05, 0.05, n), -1.2 * np.sin(s)
        q = q_d + rng.uniform(-3.4e-4, 3.4e-4, n)
        dq = dq_d + rng.uniform(-5.5e-2, 5.5e-2, n)
        tau_m = robot.compute_gravity(q) + rng.uniform(-3.0, 3.0, n)
        if k >= 100:
            tau_m[1] += push
        wrench = rng.uniform(-2.3, 2.3, 6)
        gravity = np.array([0.0, 0.0, -9.81])
        tk = t
        if faults:
            if k == 50:
                q[2] = np.nan
            elif k == 70:
                tau_m[0] = 1e6
            elif k == 90:
                tk = t - DT  # repeated stamp
            elif k == 110:
                gravity = np.array([0.0, 0.0, -5.0])
            elif k in (130, 131):
                gravity = np.array([0.1, 0.05, -9.8])  # plausible: becomes the model's gravity
            elif k == 150:
                q_d[3] = robot.upper_limit[3] + 1.0
            elif k == 170:
                wrench[4] = 500.0
            elif k == 190:
                t += 4 * DT  # a late tick: its period is clipped to the band
                tk = t
            elif k == 210:
                ddq_d[0] = np.inf
        yield k, (tk, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d)


def with_springs(robot: RobotModel) -> RobotModel:
    """The robot with joint springs (MJCF stiffness/springref), which g_hat(q) includes."""
    k_s = np.linspace(5.0, 40.0, robot.n)
    return RobotModel(robot.pin_model.copy(), ee_frame=robot.ee_frame, sensor_frame=robot.sensor_frame,
                      friction=robot.friction, home=robot.home, spring_stiffness=k_s,
                      spring_reference=robot.home + 0.1)  # fmt: skip


_SIGNALS = {  # name, unit
    SIG_T: ("measurement t", "s"),
    SIG_Q: ("measurement q", "rad"),
    SIG_DQ: ("measurement dq", "rad/s"),
    SIG_TAU_M: ("measurement tau_m", "Nm"),
    SIG_WRENCH: ("measurement wrench", "N or Nm"),
    SIG_GRAVITY: ("measurement gravity", "m/s^2"),
    SIG_Q_D: ("reference q_d", "rad"),
    SIG_DQ_D: ("reference dq_d", "rad/s"),
    SIG_DDQ_D: ("reference ddq_d", "rad/s^2"),
    SIG_MODEL: ("model", ""),
}
_BOUND_NAMES = {  # which InputBounds field sets the bound
    SIG_Q: "joint limits +- InputBounds.position_margin",
    SIG_Q_D: "joint limits +- InputBounds.position_margin",
    SIG_DQ: "InputBounds.velocity_factor x velocity limit",
    SIG_DQ_D: "InputBounds.velocity_factor x velocity limit",
    SIG_TAU_M: "InputBounds.torque_factor x torque limit",
    SIG_DDQ_D: "InputBounds.max_acceleration",
    SIG_GRAVITY: "model gravity +- InputBounds.gravity_tolerance",
}


def expected_text(fault: tuple) -> str:
    """The fault text the contract documents for (code, signal, index, value, lo, hi), written here from the
    contract's wording (the core writes its own in cpp/src/fault.cpp)."""
    code, signal, index, value, lo, hi = fault
    value, lo, hi = float(value), float(lo), float(hi)
    name, unit = _SIGNALS.get(signal, ("input", ""))
    where = f"{name}[{index}]" if index >= 0 else name
    if code == NON_FINITE:
        return f"non-finite {where} = {value!r}"
    if code == OUT_OF_BOUNDS:
        if signal == SIG_WRENCH:
            bound = "InputBounds.max_force" if index < 3 else "InputBounds.max_moment"
            unit = "N" if index < 3 else "Nm"
        elif signal == SIG_GRAVITY:
            where = f"|{name}|"
            bound = _BOUND_NAMES[signal]
        else:
            bound = _BOUND_NAMES.get(signal, "bound")
        return f"{where} = {value:.6g} {unit} outside the plausible [{lo:.6g}, {hi:.6g}] {unit} ({bound})"
    if code == TIME_NOT_INCREASING:
        return (
            f"measurement t = {value!r} s does not advance past the last accepted t = {lo!r} s "
            "(repeated or backwards time stamp)"
        )
    if code == MODEL_NON_FINITE:
        return "non-finite model terms (gravity, Coriolis, momentum or feed-forward) at this state"
    if code == MASS_NOT_POSITIVE_DEFINITE:
        return "mass matrix of the model not positive definite at this q; damping not updated"
    if code == OBSERVER_INVALID:
        return "observer state invalid (non-finite): collision detection is off until reset()"
    if code == OUTPUT_NON_FINITE:
        return f"non-finite control law on joint {index}: collision detection is off until reset()"
    return f"fault {code}"
