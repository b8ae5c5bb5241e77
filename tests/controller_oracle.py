"""An independent tick of the controller in plain numpy/Pinocchio: the oracle of the C++ core and of Controller.

Written from the paper's equations (2), (4)-(6), (9)-(13) and the contract of
:class:`reflexarm.control.Controller` with whole-vector numpy operations, ``np.linalg.cholesky``/``eigh`` for the
modal damping and no code of the package's tick. ``ticks`` is the seeded run both sides see (with bad ticks).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import pinocchio as pin

from oracle_reactions import DT, FINISHING_TICKS, RETRACT_MASS_AGE, TRACE_POINTS, OracleReactions  # noqa: F401
from reflexarm.control.collision.react import ReactionSettings
from reflexarm.control.contract import (
    NON_FINITE,
    OBSERVER_INVALID,
    OUT_OF_BOUNDS,
    SIG_DDQ_D,
    SIG_DQ,
    SIG_DQ_D,
    SIG_GRAVITY,
    SIG_Q,
    SIG_Q_D,
    SIG_T,
    SIG_TAU_M,
    SIG_WRENCH,
    TIME_NOT_INCREASING,
)
from reflexarm.robots.robot_model import RobotModel

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
class Oracle(OracleReactions):
    """One control tick in plain numpy: eqs. (2), (4)-(6), (9)-(13), the reactions and the input contract.

    The reactions and the event record are written from the documented math (the docstrings of
    ``reflexarm.control.collision.react`` / ``.event`` and of ``ReactionSettings``), not from the C++:

    * brake: tau = g + C dq - M dq / T_b (closed loop ddq = -dq / T_b) until brake_duration has passed, then hold;
    * retract: law (2) (K, D, g, C dq, M(q_d) ddq_d, kappa_f tau_f; no disturbance compensation) along the
      minimum-jerk path q_detect -> q_target over T, then hold; the motion d = M(q)^-1 J^T f (the admittance
      reflex: the velocity an impulse of f gives the free arm) moves a point along J M^-1 J^T f: the sensor frame
      along the measured force (class contact), else the far end of the most distal crossing link (the next
      joint's origin, the sensor frame for the last link), J^T f the residual on the joints up to it;
      |J d| = retract_distance, |d_i| <= max_retract_angle, T >= retract_distance / retract_speed, >= 0.1 s, and
      the path's peak speed 1.875 |d_i| / T <= velocity_fraction x v_lim_i; q_target inside the safe range; a T
      beyond max_retract_time shortens d and T in proportion (both scale with d); retract_planned = |J d|;
    * hold: law (2) with q_d = q_target, dq_d = ddq_d = 0, no disturbance compensation; compliant holds q_detect
      from the detection on (kappa_eps -> 0) at c K with the modal damping of c K, c = compliant_stiffness_factor:
      L^-1 (c K) L^-T = c U diag(lambda) U^T has the same U and c lambda, so that damping is sqrt(c) D;
    * the reaction's law replaces (2) from the detecting tick on (the event starts before that tick's law); the
      torque limits bound it like any command; every reaction's law (13 included) adds K (clip(q, safe range) - q)
      and, above a joint's velocity limit,
      -(M dq)_i / brake_time x (1 - v_lim_i / |dq_i|);
    * classification: with kappa_ext = 0, |wrist force| > contact_level at detection is a "contact"
      (contact_reaction), else a "collision" (reaction);
    * isolation (with geometry, of a collision): the plain Python ContactIsolator on the residual and posture of the
      tick ``isolation_delay`` after detection (the detecting tick for 0), its result applied ``isolation_ticks``
      accepted ticks later (the estimate's t_estimated), and the retract then planned from it: the real-time tick
      spreads the fit over the ticks (``ReactionSettings.isolation_points_per_tick``). The rule, from the
      geometry: the candidate links are the most distal joint with |r_j| > significance_j and every later one;
      each candidate point is scored twice (pass 1, the trace of J_p W W J_p^T, TRACE_POINTS points a unit, the
      link's last unit the rest; pass 2, the constrained fit, one unit a point), a candidate link without geometry
      is one unit (the wrench fit), the links fitted from the first on until the first of them within the
      tolerance of their best fit is within the tolerance itself (the later ones not fitted); the tick that begins
      does no unit, each following tick at most points_per_tick units, then one tick chooses the link (and its
      rank), one estimates its point and force, and the estimate is in on
      the tick after: ceil(units / points_per_tick) + 3 ticks after the beginning (on that tick if there are no
      units: nothing significant); a retract waiting for it is planned on the next
      accepted tick (its q and Jacobians; retracting from that tick on);
    * a retract's M(q): the modal damping's (its last crba, on an accepted tick) when that is at most
      RETRACT_MASS_AGE accepted ticks old, else M(q) of that tick; chosen on the tick the estimate comes in (for a
      retract that waited for it), else on the plan's tick;
    * the tick whose isolation comes in does not advance the reaction (brake / retract timing) that tick.
    """

    robot: RobotModel
    stiffness: float = 300.0
    damping_ratio: float = 0.7
    observer_gain: float = 5.0
    detection_observer_gain: float | None = None
    #: the detection observer subtracts the friction model with this velocity band whatever kappa_f (None: it
    #: follows kappa_f with the model's band)
    detection_friction_band: float | None = None
    #: K_f of the detection residual's second stage (None: none): the detector looks at r_f, r_f += (1 - e^{-K_f h})
    #: (r - r_f) after each observer step, 0 on the first tick
    detection_filter_gain: float | None = None
    threshold: float | None = 11.0
    reaction: str = "gravity"
    contact_reaction: str | None = None
    settings: ReactionSettings = field(default_factory=ReactionSettings)
    discretization: str = "euler"
    kappa_f: int = 0
    kappa_eps: int = 0
    kappa_ext: int = 0
    residual_limit: float = 30.0
    switch_time: float = 0.1
    damping_update_period: int = 10
    torque_rate_limit: float | None = None
    #: the links' surfaces: a collision is isolated at detection by the plain Python ContactIsolator (significance
    #: isolation_share x threshold) and a retract moves the estimated point along the estimated force
    geometry: object | None = None
    isolation_share: float = 0.25
    state: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        r, n = self.robot, self.robot.n
        self.n = n
        if self.contact_reaction is None:
            self.contact_reaction = self.reaction
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
        self.v_lim = np.where(np.isfinite(vel) & (vel > 0), vel, np.inf)
        eff = r.effort_limit
        ok = np.isfinite(eff) & (eff > 0)
        self.tau_max = np.where(ok, eff, np.inf)
        self.tau_m_max = np.where(ok, BOUNDS["torque_factor"] * np.where(ok, eff, 1.0), BOUNDS["torque"])
        self.step_max = np.full(n, np.inf if self.torque_rate_limit is None else self.torque_rate_limit * DT)
        # postures a reaction holds or moves to: position_margin inside the limits (at most a quarter of the range)
        both = np.isfinite(lo) & np.isfinite(hi)
        pm = self.settings.position_margin
        margin = np.where(both, np.minimum(pm, 0.25 * np.where(both, hi - lo, 0.0)), pm)
        self.safe_lo = np.where(np.isfinite(lo), lo + margin, -np.inf)
        self.safe_hi = np.where(np.isfinite(hi), hi - margin, np.inf)
        self.D = np.zeros((n, n))
        self.isolator = None
        if self.geometry is not None and self.threshold is not None:
            from reflexarm.control.collision import ContactIsolator

            self.isolator = ContactIsolator(r, significance=self.isolation_share * self.threshold,
                                            geometry=self.geometry)  # fmt: skip
        self.last_q = None
        self.prev_tau = None
        self.reacted = False
        self.detected = False
        self.event: dict | None = None
        self.eps_before = self.kappa_eps
        self.reset()

    def reset(self) -> None:
        if self.reacted and self.event is not None and self.event["reaction"] == "compliant":
            self.kappa_eps = self.eps_before
        self.reacted = self.detected = False
        self.event = None
        self.obs = [np.zeros((3, self.n)), np.zeros((3, self.n))]  # integral, p0, residual per observer (Euler)
        self.p_prev = np.zeros(self.n)  # exact form: the momentum of the last accepted tick
        self.r_f = np.zeros(self.n)  # the detection residual after the second stage
        self.started, self.last_t, self.invalid, self.countdown = False, None, False, 0
        self.pending: tuple[np.ndarray | None, int] | None = None  # (next D, accepted ticks until it is used)
        self.full = True
        self.eps_w = float(self.kappa_eps)
        self.dq_f: np.ndarray | None = None  # the guard's low-passed dq and M(q) dq
        self.p_f = np.zeros(self.n)
        self.isolating: tuple[Any, int] | None = None  # (estimate, ticks until it is in) of an isolation under way
        self.retract_due: np.ndarray | None = None  # the retract's M, chosen on the tick the estimate came in: plan due
        self.mass: np.ndarray | None = None  # M(q) of the damping's last crba (on an accepted tick) ...
        self.mass_age = 1 << 20  # ... and the accepted ticks since
        self.retract_mass = ""  # which M(q) the retract's plan used: "damping" (the damping's) or "own" (its tick's)
        self.t_estimate = self.t_estimated = math.nan

    def set_switches(self, kappa_eps: int) -> None:
        self.kappa_eps = kappa_eps
        if self.switch_time == 0.0:
            self.eps_w = float(kappa_eps)

    @property
    def gravity_mode(self) -> bool:
        return self.reacted and self.event is not None and self.event["reaction"] == "gravity"

    @property
    def mode(self) -> str:
        if self.gravity_mode:
            return "gravity_compensation"
        if self.reacted and self.event is not None:
            phase = self.event["phase"]
            if phase in ("braking", "retracting"):
                return phase
            if phase == "holding" and self.event["reaction"] != "compliant":
                return "holding"
        if not self.kappa_eps:
            return "compliant"
        return "precise_ee_compliant" if self.kappa_ext else "precise_stiff"

    def r_det(self) -> np.ndarray:
        """The residual the detector looks at."""
        return self.r_obs() if self.detection_filter_gain is None else self.r_f

    def r_obs(self) -> np.ndarray:
        """The detection observer's residual (the first observer's without one), before the second stage."""
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
        # D from M(q) every damping_update_period accepted ticks, put in use min(DAMPING_TICKS, period) - 1 ticks
        # later (the core spreads the computation over that many ticks); whole on the first tick after a reset
        D: np.ndarray | None = self.D
        pending, full, mass = self.pending, self.full, None
        if self.gravity_mode:
            pending = None
        elif self.countdown == 0:
            Mu = pin.crba(model, self.data, q)
            mass = np.triu(Mu) + np.triu(Mu, 1).T
            new_D = self.modal_damping(mass)
            span = 1 if full else min(DAMPING_TICKS, self.damping_update_period)
            D, pending = (new_D, None) if span == 1 else (D, (new_D, span - 1))
            full = False
        elif pending is not None:
            pending = (pending[0], pending[1] - 1)
            if pending[1] == 0:
                D, pending = pending[0], None
        assert D is not None and all(np.all(np.isfinite(x)) for x in (g, C, p, ff, J))
        self.D, self.last_q, self.pending, self.full = D, q.copy(), pending, full
        self.mass, self.mass_age = (mass, 0) if mass is not None else (self.mass, min(self.mass_age + 1, 1 << 20))
        h = DT if self.last_t is None else min(max(t - self.last_t, 0.5 * DT), 2.0 * DT)
        self.last_t = t
        if self.invalid:
            return self.reject((OBSERVER_INVALID, 0, -1, 0.0, 0.0, 0.0))
        fr = self.robot.friction
        tau_f = fr.coulomb * np.clip(dq / fr.velocity_band, -1, 1) + fr.viscous * dq
        if not self.started:
            for o in self.obs:
                o[0], o[1], o[2] = 0.0, p, 0.0
            self.p_prev = p.copy()
            self.r_f = np.zeros(n)
            self.started = True
        else:
            beta = tau_m - (g - C.T @ dq) - (self.kappa_f * tau_f - J.T @ wrench)  # tau_m - gamma - alpha, (4)-(6)
            beta_det = beta
            if self.detection_friction_band is not None:
                tau_f_det = fr.coulomb * np.clip(dq / self.detection_friction_band, -1, 1) + fr.viscous * dq
                beta_det = tau_m - (g - C.T @ dq) - (tau_f_det - J.T @ wrench)
            self.observe(p, (beta, beta_det), h)
            if self.detection_filter_gain is not None:
                b = math.exp(-self.detection_filter_gain * h)
                self.r_f = b * self.r_f + (1.0 - b) * self.r_obs()
        if not all(np.all(np.isfinite(o)) for o in self.obs):
            self.invalid = True
            return self.reject((OBSERVER_INVALID, 0, -1, 0.0, 0.0, 0.0))
        over = np.abs(self.r_det()) > (np.inf if self.threshold is None else self.threshold)
        started = self.threshold is not None and self.begin(t, q, dq, p, wrench, over)
        # the kappa_eps ramp after the event's start (a compliant reaction switches kappa_eps off on the detecting tick)
        eps_w = self.eps_w
        if eps_w != self.kappa_eps:
            inc = DT / self.switch_time
            eps_w = min(eps_w + inc, 1.0) if self.kappa_eps > eps_w else max(eps_w - inc, 0.0)
        tau = self.reaction_torque(t, q, dq, g, C, p, tau_f)
        if tau is None:
            r = np.clip(self.obs[0][2], -self.residual_limit, self.residual_limit)
            tau = self.stiffness * (q_d - q) + D @ (dq_d - dq) + g + C @ dq + ff + self.kappa_f * tau_f - eps_w * r
        bounded = self.bound(tau)
        saturated = bounded != tau
        self.model.gravity.linear, self.gravity = gravity, gravity.copy()
        self.eps_w = eps_w
        if not self.gravity_mode:
            self.countdown = (self.countdown or self.damping_update_period) - 1
        if self.threshold is not None and self.detected and not started:
            self.advance(t, q, dq, over, saturated)
        return {"code": 0, "tau": bounded, "residual": self.r_det().copy(), "collision": self.detected,
                "collided": over, "saturated": saturated, "mode": self.mode, "fault": None}  # fmt: skip

    def observe(self, p: np.ndarray, betas: tuple[np.ndarray, np.ndarray], h: float) -> None:
        """Both observers over the period h (each its beta): Euler of (4), or the exact form of the first-order
        filter dr/dt = K_o (tau_ext - r) whose input over the period is the mean (p_k - p_{k-1}) / h - beta."""
        gains = (self.observer_gain, self.detection_observer_gain)
        for o, k_o, beta in zip(self.obs, gains, betas, strict=True):
            if k_o is None:
                continue
            if self.discretization == "exact":
                o[2] = self.exact_step(o[2], k_o, h, p - self.p_prev, beta)
            else:
                o[0] += h * (beta + o[2])
                o[2] = k_o * (p - o[1] - o[0])
        self.p_prev = p.copy()

    @staticmethod
    def exact_step(r: np.ndarray, k_o: float, h: float, dp: np.ndarray, beta: np.ndarray) -> np.ndarray:
        decay = math.exp(-k_o * h)
        return decay * r + (1.0 - decay) * (dp / h - beta)

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



def core_controller(core: Any, robot: RobotModel, o: Oracle, dt: float = DT, **changes: float) -> Any:
    """The C++ controller with the oracle's settings (the model crosses as pin.Model.saveToString text).
    ``dt``: its nominal period (the oracle's is DT); ``changes``: ReactionParams fields to set differently from the
    oracle (a deliberately broken twin)."""
    p = core.ControllerParams()
    p.stiffness, p.damping_ratio = np.array([o.stiffness]), np.array([o.damping_ratio])
    p.observer_gain = np.array([o.observer_gain])
    det = o.detection_observer_gain
    p.detection_observer_gain = np.zeros(0) if det is None else np.array([det])
    if o.detection_friction_band is not None:
        p.detection_kappa_f, p.detection_friction_velocity_band = 1, o.detection_friction_band
    if o.detection_filter_gain is not None:
        p.detection_filter_gain = np.array([o.detection_filter_gain])
    p.threshold = np.zeros(0) if o.threshold is None else np.array([o.threshold])
    p.reaction, p.contact_reaction = o.reaction, o.contact_reaction
    p.observer_discretization = o.discretization
    rp = core.ReactionParams()
    for f in fields(o.settings):
        value = changes.get(f.name, getattr(o.settings, f.name))
        exact = {"isolation_points_per_tick": int, "retract_waits_for_estimate": bool}.get(f.name, float)
        setattr(rp, f.name, exact(value))
    p.reaction_params = rp
    p.kappa_f, p.kappa_eps, p.kappa_ext = o.kappa_f, o.kappa_eps, o.kappa_ext
    p.residual_limit, p.switch_time, p.dt = o.residual_limit, o.switch_time, dt
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


def ticks(
    robot,
    *,
    seed: int = 0,
    push: float | Callable[[int], float] = 0.0,
    wrist_force: tuple[float, float, float] = (0.0, 0.0, 0.0),
    faults: bool = True,
    n_ticks: int = N_TICKS,
):
    """(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) along a seeded random reference, with bad ticks.

    ``push``: added to tau_m[1] from tick 100 on [Nm] (a function of the tick: any profile); ``wrist_force``: added
    to the measured wrist force from tick 100 on [N] (in the sensor frame)."""
    rng = np.random.default_rng(seed)
    n = robot.n
    phase = rng.uniform(0, 2 * np.pi, n)
    t = 0.0
    for k in range(n_ticks):
        t += DT
        s = 2.0 * t + phase
        q_d = robot.home + 0.3 * np.sin(s) + rng.uniform(-0.01, 0.01, n)
        dq_d, ddq_d = 0.6 * np.cos(s) + rng.uniform(-0.05, 0.05, n), -1.2 * np.sin(s)
        q = q_d + rng.uniform(-3.4e-4, 3.4e-4, n)
        dq = dq_d + rng.uniform(-5.5e-2, 5.5e-2, n)
        tau_m = robot.compute_gravity(q) + rng.uniform(-3.0, 3.0, n)
        wrench = rng.uniform(-2.3, 2.3, 6)
        if k >= 100:
            tau_m[1] += push(k) if callable(push) else push
            wrench[:3] += wrist_force
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
