"""The reactions part of the plain oracle (``controller_oracle.Oracle``): detection's event, the isolation's timing, the
brake / retract / compliant / gravity laws and the event record after detection, written from the class docstring of
``controller_oracle.Oracle`` (its rules) with whole-vector numpy operations and no code of the package's tick.

A mixin: ``Oracle`` inherits it and provides the state (settings, model, the event dict, the switches).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

#: The oracle's nominal period [s] (controller_oracle's DT, imported from here).
DT = 1e-3

#: The retract plans with the M(q) of the modal damping's last crba when that is at most this many accepted ticks old,
#: else with M(q) of its own tick: the contract of Controller::kRetractMassAge (cpp/include/reflexarm/controller.hpp).
RETRACT_MASS_AGE = 10

#: Ticks of a collision's isolation after its fit (the class docstring's rule): one chooses the link and its rank,
#: one estimates its point and force, and on the next the estimate is in (a waiting retract is planned on the tick
#: after).
FINISHING_TICKS = 3
#: Pass-1 points per unit of the isolation's work (ContactIsolator::kTracePoints, cpp/include/reflexarm/isolation.hpp).
TRACE_POINTS = 16


def min_jerk(s: float) -> tuple[float, float, float]:
    """The minimum-jerk profile at s = t / T in [0, 1]: position s^3 (10 - 15 s + 6 s^2) (the quintic with
    x(0) = x'(0) = x''(0) = 0, x(1) = 1, x'(1) = x''(1) = 0) and its first two derivatives with respect to s."""
    return (s**3 * (10.0 - 15.0 * s + 6.0 * s * s), 30.0 * s * s * (1.0 - s) ** 2,
            60.0 * s * (1.0 - 3.0 * s + 2.0 * s * s))  # fmt: skip


class OracleReactions:
    """The reactions' methods of :class:`controller_oracle.Oracle` (see its docstring for the rules)."""

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
        elif reaction == "retract" and self.awaiting and rs.retract_waits_for_estimate:  # brake until isolated
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
        last = ev["distal_joint"]
        if self.isolator is not None:  # the most distal significant joint at detection, at least the crossing one
            significant = np.flatnonzero(np.abs(ev["residual"]) > self.isolation_share * self.threshold)
            last = max(last, int(significant[-1])) if significant.size else last
        last = est.link if est is not None and est.link >= 0 else last
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
            if self.reacted and ev["reaction"] == "retract" and rs.retract_waits_for_estimate:  # M now, plan next
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
