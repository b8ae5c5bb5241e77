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

from reflexarm.control.collision.react import ReactionSettings
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
#: The retract plans with the M(q) of the modal damping's last crba when that is at most this many accepted ticks old,
#: else with M(q) of its own tick: the contract of Controller::kRetractMassAge (cpp/include/reflexarm/controller.hpp).
RETRACT_MASS_AGE = 10

#: Ticks of a collision's isolation after its fit (the class docstring's rule): one chooses the link and its rank,
#: one estimates its point and force, and on the next the estimate is in (a waiting retract is planned on the tick
#: after).
FINISHING_TICKS = 3
#: Pass-1 points per unit of the isolation's work (ContactIsolator::kTracePoints, cpp/include/reflexarm/isolation.hpp).
TRACE_POINTS = 16

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


def min_jerk(s: float) -> tuple[float, float, float]:
    """The minimum-jerk profile at s = t / T in [0, 1]: position s^3 (10 - 15 s + 6 s^2) (the quintic with
    x(0) = x'(0) = x''(0) = 0, x(1) = 1, x'(1) = x''(1) = 0) and its first two derivatives with respect to s."""
    return (s**3 * (10.0 - 15.0 * s + 6.0 * s * s), 30.0 * s * s * (1.0 - s) ** 2,
            60.0 * s * (1.0 - 3.0 * s + 2.0 * s * s))  # fmt: skip


@dataclass
class Oracle:
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

    # ------------------------------------------------------------------ reactions
    def reaction_torque(self, t, q, dq, g, C, p, tau_f) -> np.ndarray | None:
        """The reaction's law on this tick (None: law (2)); the event's phase is the one the last tick left, or the
        one the event started in on the detecting tick."""
        if self.gravity_mode:
            return g + self.limits(q, dq, p)  # (13)
        ev = self.event
        if not self.reacted or ev is None or ev["phase"] not in ("braking", "retracting", "holding"):
            return None
        return self.reaction_law(t, q, dq, g, C, p, tau_f) + self.limits(q, dq, p)

    def limits(self, q, dq, p) -> np.ndarray:
        """What every reaction adds: K (safe bound - q) outside the safe range; above the velocity limit, the
        brake's damping M dq / T_b times the excess share (1 - v_lim / |dq|)."""
        out = self.stiffness * (np.clip(q, self.safe_lo, self.safe_hi) - q)
        speed = np.abs(dq)
        fast = speed > self.v_lim
        out[fast] -= p[fast] / self.settings.brake_time * (1.0 - self.v_lim[fast] / speed[fast])
        return out

    def reaction_law(self, t, q, dq, g, C, p, tau_f) -> np.ndarray:
        ev = self.event
        assert ev is not None
        if ev["phase"] == "braking":  # M ddq = -M dq / T_b after the model terms cancel
            return g + C @ dq - p / self.settings.brake_time
        q_d, dq_d, ff = ev["q_target"], np.zeros(self.n), np.zeros(self.n)
        D = self.hold_damping * self.D
        if ev["phase"] == "retracting":
            D = self.D
            T = self.retract_time
            pos, vel, acc = min_jerk(min(max((t - self.t_phase) / T, 0.0), 1.0))
            q_d = self.q_from + pos * self.dq_plan
            dq_d = vel / T * self.dq_plan
            ff = pin.rnea(self.model0, self.data0, q_d, np.zeros(self.n), acc / T**2 * self.dq_plan)  # M(q_d) ddq_d
        return self.k_hold * (q_d - q) + D @ (dq_d - dq) + g + C @ dq + ff + self.kappa_f * tau_f

    def energy(self) -> float:
        assert self.dq_f is not None
        return 0.5 * float(self.dq_f @ self.p_f)

    def begin(self, t, q, dq, p, wrench, over) -> bool:
        """Before the law: low-pass dq and M dq; start the event on the first detection (True), so that the
        reaction's law makes the detecting tick's torque already."""
        if self.dq_f is None:
            self.dq_f, self.p_f = dq.copy(), p.copy()
        else:
            a = DT / (self.settings.energy_filter_time + DT)
            self.dq_f = self.dq_f + a * (dq - self.dq_f)
            self.p_f = self.p_f + a * (p - self.p_f)
        if over.any() and not self.detected:
            self.detected = True
            self.start(t, q, wrench, over)
            return True
        return False

    def start(self, t, q, wrench, over) -> None:
        rs, zeta = self.settings, self.threshold
        r = self.r_det().copy()
        force = float(np.linalg.norm(wrench[:3]))
        measured = not self.kappa_ext and force > rs.contact_level
        reaction = self.contact_reaction if measured else self.reaction
        e = self.energy()
        # the isolation of a collision (plain Python ContactIsolator), when geometry is given: isolation_delay after
        # detection, from the detection residual of that tick (at once for a delay of 0)
        self.estimate = None
        self.awaiting = self.isolator is not None and not measured
        if self.awaiting and self.settings.isolation_delay <= 0.0:
            self.begin_isolation(t, q, r)
        self.event = ev = {
            "detected": True, "t_detect": t, "joints": over.copy(), "distal_joint": int(np.flatnonzero(over)[-1]),
            "contact_class": "contact" if measured else "collision", "reaction": reaction, "phase": "none",
            "residual": r, "q_detect": q.copy(), "q_target": q.copy(), "retract_planned": math.nan,
            "wrist_force": force,
            "peak_residual": float(np.max(np.abs(r)) / zeta), "energy_detect": e, "energy_rest": math.nan,
            "energy_max": e, "moved": 0.0, "t_hold": math.nan, "recrossings": 0, "torque_limited": False,
            "overspeed": False, "still_moving": False, "guard_checked": False, "text": "",
        }  # fmt: skip
        self.armed = False  # a re-contact needs the residual below half of every threshold first
        self.t_phase, self.q_from, self.k_hold = t, q.copy(), np.full(self.n, float(self.stiffness))
        self.hold_damping = 1.0  # the hold's damping is this x D
        if reaction == "gravity":
            ev["phase"] = "gravity"
        elif reaction == "brake":
            ev["phase"] = "braking"
        elif reaction == "retract" and self.awaiting:  # brake until isolated, then retract from the estimate
            ev["phase"] = "braking"
        elif reaction == "retract":
            self.plan_retract(q, wrench, measured, self.retract_mass_matrix(q))
            ev["phase"] = "retracting"
        elif reaction == "compliant":
            ev["q_target"] = np.clip(q, self.safe_lo, self.safe_hi)
            self.k_hold = rs.compliant_stiffness_factor * self.k_hold
            self.hold_damping = math.sqrt(rs.compliant_stiffness_factor)  # the modal damping of c K
            ev["phase"], ev["t_hold"] = "holding", t
            self.eps_before = self.kappa_eps
            self.set_switches(0)
        self.reacted = reaction != "none"

    def isolation_ticks(self, q: np.ndarray, r: np.ndarray) -> int:
        """Ticks after its beginning on which the isolation of residual r at q is in (the class docstring's rule)."""
        significant = np.flatnonzero(np.abs(r) > self.isolation_share * self.threshold)
        if significant.size == 0:
            return 0
        assert self.isolator is not None
        best = [f.best_error for f in self.isolator.fit(q, r)]  # every candidate link's best fit, in order
        tol, examined = self.isolator.tolerance(r), len(best)
        for k in range(1, len(best) + 1):  # the links fitted until the first within tol of their best is within tol
            first = next(e for e in best[:k] if e <= min(best[:k]) + tol)
            if first <= tol:
                examined = k
                break
        counts = self.geometry.point_counts()[significant[-1] :][:examined]  # type: ignore[attr-defined]
        units = int(np.sum(np.where(counts > 0, -(-counts // TRACE_POINTS) + counts, 1)))
        return -(-units // self.settings.isolation_points_per_tick) + FINISHING_TICKS

    def begin_isolation(self, t, q, r) -> bool:
        """Isolate (q, r) of this tick; the estimate is in after isolation_ticks. True if it is in now."""
        assert self.isolator is not None
        self.t_estimate = t
        self.isolating = (self.isolator.isolate(q, r.copy()), self.isolation_ticks(q, r))
        return self.step_isolation(t, count=False)

    def step_isolation(self, t, count: bool = True) -> bool:
        """One tick of the isolation under way; True (and the estimate in) when its ticks ran out."""
        assert self.isolating is not None
        estimate, left = self.isolating
        left -= int(count)
        if left > 0:
            self.isolating = (estimate, left)
            return False
        self.estimate, self.awaiting, self.isolating, self.t_estimated = estimate, False, None, t
        return True

    def retract_direction(self, q, wrench, measured) -> tuple[np.ndarray, list[np.ndarray], int]:
        """(d, Js, last): the joint direction J^T f, the translational Jacobians (rows in any frame: only |J d| is used)
        of the points whose motion sets the retract's scale, and the last joint that moves the contact."""
        ev, n = self.event, self.n
        assert ev is not None
        est = self.estimate
        if est is not None and est.point is not None and est.force is not None:
            # the estimated point along the estimated force: J_p = J_v + J_w x (p - o) of its link's joint
            pin.computeJointJacobians(self.model, self.data, q)
            J6 = pin.getJointJacobian(self.model, self.data, est.link + 1, pin.LOCAL_WORLD_ALIGNED)
            arm = est.point - self.data.oMi[est.link + 1].translation
            Jp = J6[:3] + np.cross(J6[3:].T, arm).T
            return Jp.T @ (est.force / np.linalg.norm(est.force)), [Jp], est.link
        sensor = pin.computeFrameJacobian(self.model, self.data, q, self.robot.sensor_frame_id, pin.LOCAL)[:3]
        if measured:  # the sensor frame (LOCAL: the wrench is measured in it); J d = J J^T f along the force
            return sensor.T @ wrench[:3], [sensor], n - 1
        last = est.link if est is not None and est.link >= 0 else ev["distal_joint"]
        last = n - 1 if last < 0 else last
        d = np.zeros(n)
        d[: last + 1] = ev["residual"][: last + 1]  # r = J_c^T f on the joints a force on that link reaches
        # the point on the link is unknown: every point from its far end on (the later joints' origins, Pinocchio id
        # i + 1 for joint i, and the sensor frame) bounds the motion
        Js = [pin.computeJointJacobian(self.model, self.data, q, j)[:3] for j in range(last + 2, self.model.njoints)]
        return d, [*Js, sensor], last

    def retract_mass_matrix(self, q) -> np.ndarray:
        """The retract's M: the modal damping's when it is at most RETRACT_MASS_AGE ticks old, else M(q)."""
        self.retract_mass = "damping" if self.mass is not None and self.mass_age <= RETRACT_MASS_AGE else "own"
        if self.retract_mass == "damping":
            assert self.mass is not None
            return self.mass
        Mu = pin.crba(self.model, self.data, q)
        return np.triu(Mu) + np.triu(Mu, 1).T

    def plan_retract(self, q, wrench, measured, M: np.ndarray) -> None:
        """The retract's plan at q with M, the caller's retract_mass_matrix: of this tick, or for a retract that
        waited for the isolation of the tick its estimate came in."""
        rs, ev = self.settings, self.event
        assert ev is not None
        d, Js, last = self.retract_direction(q, wrench, measured)
        k = last + 1  # the admittance reflex of the joints up to the contact's link; the later ones stay put
        d = np.concatenate([np.linalg.solve(M[:k, :k], d[:k]), np.zeros(self.n - k)])
        if np.linalg.norm(d) > 0:
            d = d / np.linalg.norm(d)

        def motion(dq: np.ndarray) -> float:  # the farthest-moving point [m]
            return max(float(np.linalg.norm(J[:, :k] @ dq[:k])) for J in Js)

        moved = motion(d)  # [m/rad]
        scale = rs.retract_distance / moved if moved > 1e-9 else rs.max_retract_angle
        scale = min(scale, rs.max_retract_angle / float(np.max(np.abs(d)))) if np.any(d) else scale
        goal = np.clip(q + scale * d, self.safe_lo, self.safe_hi)
        self.dq_plan = goal - q
        finite = np.isfinite(self.v_lim)
        peak = 1.875 * np.abs(self.dq_plan[finite]) / (rs.velocity_fraction * self.v_lim[finite])
        self.retract_time = max(0.1, rs.retract_distance / rs.retract_speed, *peak.tolist())
        if self.retract_time > rs.max_retract_time:  # shortened: distance and duration scale together
            self.dq_plan = self.dq_plan * (rs.max_retract_time / self.retract_time)
            self.retract_time = rs.max_retract_time
        ev["q_target"] = q + self.dq_plan
        ev["retract_planned"] = motion(self.dq_plan)

    def advance(self, t, q, dq, over, saturated) -> None:
        """A tick after the detecting one: phase changes, then the record (peak, motion, re-contacts, guard)."""
        ev, rs, zeta = self.event, self.settings, self.threshold
        assert ev is not None and zeta is not None
        isolated = False  # the isolation's estimate is in on this tick
        if self.isolating is not None:
            isolated = self.step_isolation(t)
        elif self.awaiting and t - ev["t_detect"] >= rs.isolation_delay - 1e-12:
            isolated = self.begin_isolation(t, q, self.r_det())
        if isolated:
            if self.reacted and ev["reaction"] == "retract":  # its M chosen now, the plan on the next tick
                self.retract_due = self.retract_mass_matrix(q)
        elif self.retract_due is not None:  # the retract from the estimate, on this tick's q
            self.plan_retract(q, np.zeros(6), False, self.retract_due)
            self.retract_due = None
            ev["phase"], self.t_phase, self.q_from = "retracting", t, q.copy()
        elif self.reacted:
            braking = ev["phase"] == "braking" and ev["reaction"] == "brake"
            done_braking = braking and t - self.t_phase >= rs.brake_duration
            done_retracting = ev["phase"] == "retracting" and t - self.t_phase >= self.retract_time
            if done_braking:
                ev["q_target"] = np.clip(q, self.safe_lo, self.safe_hi)  # hold where the brake stopped it
            if done_braking or done_retracting:
                ev["phase"], ev["t_hold"], self.t_phase = "holding", t, t
        r = self.r_det()
        ev["peak_residual"] = max(ev["peak_residual"], float(np.max(np.abs(r))) / zeta)
        ev["moved"] = max(ev["moved"], float(np.max(np.abs(q - ev["q_detect"]))))
        if self.reacted and np.any(np.abs(dq) > self.v_lim):
            ev["overspeed"] = True
        if np.all(np.abs(r) < 0.5 * zeta):
            self.armed = True
        elif self.armed and over.any():  # a detection again after the residual fell below half of every threshold
            ev["recrossings"] += 1
            self.armed = False
        if self.reacted and saturated.any() and ev["phase"] != "gravity":
            ev["torque_limited"] = True
        e = self.energy()
        ev["energy_max"] = max(ev["energy_max"], e)
        if not ev["guard_checked"] and t - ev["t_detect"] >= rs.rest_time:
            ev["guard_checked"], ev["energy_rest"] = True, e
            level = max(rs.rest_energy_fraction * ev["energy_detect"], rs.rest_energy_floor)
            if ev["reaction"] != "none" and e > level:
                ev["still_moving"] = True
                ev["text"] = (
                    f"reaction {ev['reaction']} left the arm moving: kinetic energy {e:.3g} J "
                    f"{t - ev['t_detect']:.3g} s after detection ({ev['energy_detect']:.3g} J at detection; "
                    f"rest level {level:.3g} J)" + ("; its torque was saturated" if ev["torque_limited"] else "")
                )


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
        setattr(rp, f.name, int(value) if f.name == "isolation_points_per_tick" else float(value))
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


#: Event fields that are arrays, times or energies (compared with a tolerance); the others compare exactly.
EVENT_ARRAYS = ("residual", "q_detect", "q_target")


def event_mismatches(want: dict | None, got: dict, atol: float) -> list[str]:
    """The fields of an event record (the core's dict, or the Python CollisionEvent as one with a 0/1 joint mask)
    that differ from the oracle's: arrays and floats beyond ``atol`` (NaN equals NaN), the rest exactly."""
    if want is None:
        return [] if not got["detected"] else ["detected: core True, oracle False"]
    bad = []
    for key, w in want.items():
        g = got[key]
        if key == "joints":
            same = np.array_equal(np.asarray(g).astype(bool), w)
        elif key in EVENT_ARRAYS or isinstance(w, float):
            a, b = np.asarray(g, dtype=float), np.asarray(w, dtype=float)
            same = a.shape == b.shape and bool(np.all((np.abs(a - b) <= atol) | (np.isnan(a) & np.isnan(b))))
        else:
            same = g == w
        if not same:
            bad.append(f"{key}: core {g!r}, oracle {w!r}")
    return bad
