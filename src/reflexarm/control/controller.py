"""Controller: impedance control (2) + momentum observer (4)-(6) + collision detection (12) and reaction (13).

One object behind ``step(measurement, reference) -> Command``. The dynamics terms are evaluated once per
tick and shared by the control law and the observer(s).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from reflexarm._validation import as_positive_scalar, as_switch
from reflexarm.control import _kernels as _k
from reflexarm.control.collision import CollisionDetector
from reflexarm.control.impedance import JointImpedanceController
from reflexarm.control.momentum_observer import MomentumObserver
from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Command, Measurement, Reference

__all__ = ["MODES", "REACTIONS", "Controller"]

#: Reactions to a detected collision: eq. (13) gravity compensation; switch to the compliant mode
#: (kappa_eps = 0, Fig. 3); or none (detection is reported only).
REACTIONS = ("gravity", "compliant", "none")

#: Mode names reported in :attr:`Command.mode`.
MODES = (
    "compliant",  # kappa_eps = 0: closed loop (3)
    "precise_stiff",  # kappa_eps = 1, kappa_ext = 0: closed loop (10)
    "precise_ee_compliant",  # kappa_eps = kappa_ext = 1: closed loop (11)
    "gravity_compensation",  # reaction (13)
    "fault",  # unusable measurement: safe command
)


class Controller:
    """Joint impedance controller with momentum observer, disturbance compensation and collision handling.

    Args:
        robot: the controller's model (M_hat, C_hat, g_hat, tau_f_hat, Jacobian of the wrist sensor
            frame); a private copy is kept, so the caller's object is never modified.
        stiffness: K [Nm/rad], positive, scalar or (n,).
        damping_ratio: modal damping D_xi [-], scalar or (n,).
        observer_gain: K_o [1/s] of the observer used for compensation and detection.
        detection_observer_gain: if given, a second, usually faster observer with this gain runs in
            parallel and is the one used for detection (the paper's proposal at the end of Sec. III-A);
            the first observer is then used for compensation only.
        threshold: zeta [Nm] per joint for collision detection (12); ``None`` disables detection.
        reaction: what a detected collision does: ``"gravity"`` (13), ``"compliant"`` (kappa_eps -> 0)
            or ``"none"``. Reactions latch until :meth:`reset`.
        kappa_f: friction compensation in (2) and in the observer (6) (0/1).
        kappa_eps: disturbance compensation in (2) (0/1).
        kappa_ext: wrist-wrench term in the observer (6), "EFC" (0/1).
        residual_limit: cut-off of the observer output used for compensation [Nm] (paper: 30).
        switch_time: kappa_eps changes are ramped linearly over this time [s] so that a switch causes
            no torque jump (bumpless); 0 switches at once.
        dt: control period [s] (default 1 kHz).
        damping_update_period: see :class:`JointImpedanceController`.
    """

    def __init__(
        self,
        robot: RobotModel,
        *,
        stiffness: npt.ArrayLike = 300.0,
        damping_ratio: npt.ArrayLike = 0.7,
        observer_gain: npt.ArrayLike = 5.0,
        detection_observer_gain: npt.ArrayLike | None = None,
        threshold: npt.ArrayLike | None = 11.0,
        reaction: str = "gravity",
        kappa_f: int = 0,
        kappa_eps: int = 0,
        kappa_ext: int = 0,
        residual_limit: float = 30.0,
        switch_time: float = 0.1,
        dt: float = 1e-3,
        damping_update_period: int = 10,
    ) -> None:
        self.dt = as_positive_scalar(dt, "dt")
        self.impedance = JointImpedanceController(
            robot,
            stiffness=stiffness,
            damping_ratio=damping_ratio,
            kappa_f=kappa_f,
            damping_update_period=damping_update_period,
        )
        self.robot = self.impedance.robot  # the private copy
        n = self.robot.n
        self.n = n
        # observer states live in one array the compiled tick updates: rows 0-2 compensation, 3-5 detection
        self._obs = np.zeros((6, n))
        self.observer = MomentumObserver(n, observer_gain, self.dt, _state=self._obs[0:3])
        self.detection_observer = (
            None
            if detection_observer_gain is None
            else MomentumObserver(n, detection_observer_gain, self.dt, _state=self._obs[3:6])
        )
        self.detector = None if threshold is None else CollisionDetector(n, threshold)
        if reaction not in REACTIONS:
            raise ConfigError(f"unknown reaction {reaction!r}; choose one of: {', '.join(REACTIONS)}")
        self.reaction = reaction
        self.kappa_f = as_switch(kappa_f, "kappa_f")
        self.kappa_eps = as_switch(kappa_eps, "kappa_eps")
        self.kappa_ext = as_switch(kappa_ext, "kappa_ext")
        self.residual_limit = as_positive_scalar(residual_limit, "residual_limit")
        if not (isinstance(switch_time, (int, float)) and math.isfinite(switch_time) and switch_time >= 0):
            raise ConfigError(f"switch_time must be a non-negative number of seconds; got {switch_time!r}")
        self.switch_time = float(switch_time)
        self._eps_weight = float(self.kappa_eps)  # ramped kappa_eps actually applied
        self._kappa_eps_before_reaction = self.kappa_eps

        model = self.robot.pin_model
        self._model = model
        self._data_g = model.createData()
        self._data_c = model.createData()
        self._data_j = model.createData()
        self._model0 = self.impedance.model_no_gravity  # M(q) dq as a zero-gravity RNEA
        self._data_p = self._model0.createData()
        self._sensor_id = self.robot.sensor_frame_id
        # parameters and state of the compiled tick, see control/_kernels.py
        self._gains = np.zeros((6, n))
        self._gains[_k.K_ROW] = self.impedance.gains.stiffness
        self._gains[_k.KO_ROW] = self.observer.observer_gain
        if self.detection_observer is not None:
            self._gains[_k.KO_DET_ROW] = self.detection_observer.observer_gain
        self._gains[_k.THRESHOLD_ROW] = np.inf if self.detector is None else self.detector.threshold
        self._gains[_k.COULOMB_ROW] = self.robot.friction.coulomb
        self._gains[_k.VISCOUS_ROW] = self.robot.friction.viscous
        self._flags = np.zeros(_k.N_FLAGS)
        self._flags[_k.DT] = self.dt
        self._flags[_k.INV_BAND] = 1.0 / self.robot.friction.velocity_band
        self._flags[_k.LIMIT] = self.residual_limit
        self._flags[_k.USE_DET] = float(self.detection_observer is not None)
        self._zeros = np.zeros(n)
        self._zeros6n = np.zeros((6, n))
        self._tau = np.zeros(n)
        self._over = np.zeros(n, dtype=np.bool_)
        self._gravity = np.asarray(model.gravity.linear, dtype=float).copy()
        self._last_q = np.zeros(n)
        self._has_last_q = False
        self._started = False
        self.reacted = False
        self.last_fault = ""

    # ------------------------------------------------------------------ run-time switches
    def set_switches(
        self, *, kappa_f: int | None = None, kappa_eps: int | None = None, kappa_ext: int | None = None
    ) -> None:
        """Flip kappa_f / kappa_eps / kappa_ext at run time (kappa_eps is ramped over ``switch_time``).

        kappa_ext only enters the observer's integrand (6), so flipping it moves the residual continuously.
        """
        if kappa_f is not None:
            self.kappa_f = as_switch(kappa_f, "kappa_f")
            self.impedance.kappa_f = self.kappa_f
        if kappa_eps is not None:
            self.kappa_eps = as_switch(kappa_eps, "kappa_eps")
            if self.switch_time == 0.0:
                self._eps_weight = float(self.kappa_eps)
        if kappa_ext is not None:
            self.kappa_ext = as_switch(kappa_ext, "kappa_ext")

    @property
    def mode(self) -> str:
        """Active mode name (see :data:`MODES`)."""
        if self.reacted and self.reaction == "gravity":
            return "gravity_compensation"
        if not self.kappa_eps:
            return "compliant"
        return "precise_ee_compliant" if self.kappa_ext else "precise_stiff"

    @property
    def detection_residual(self) -> np.ndarray:
        """The residual the detector looks at."""
        return (self.detection_observer or self.observer).residual

    def reset(self) -> None:
        """Clear observer states, the latched collision and reaction; the next step re-initialises.

        After a ``"compliant"`` reaction the kappa_eps active before it is restored.
        """
        if self.reacted and self.reaction == "compliant":
            self.kappa_eps = self._kappa_eps_before_reaction
        self._started = False
        self.reacted = False
        self.last_fault = ""
        self.observer.reset()
        if self.detection_observer is not None:
            self.detection_observer.reset()
        if self.detector is not None:
            self.detector.reset()
        self.impedance.reset()
        self._eps_weight = float(self.kappa_eps)

    # ------------------------------------------------------------------ the tick
    def _safe_command(self, fault: str) -> Command:
        """Gravity compensation at the last valid state, or zero torque if there is none."""
        self.last_fault = fault
        if not self._has_last_q:
            tau = np.zeros(self.n)
        else:
            self._model.gravity.linear = self._gravity
            tau = np.array(pin.computeGeneralizedGravity(self._model, self._data_g, self._last_q))
            if not np.all(np.isfinite(tau)):
                tau = np.zeros(self.n)
        r = self.detection_residual.copy()
        collided = self.detector.detected if self.detector is not None else False
        return Command(tau, r, collided, (), "fault", fault)

    def step(self, measurement: Measurement, reference: Reference) -> Command:
        """One control tick: eq. (2) with the observer (4)-(6), detection (12) and reaction (13).

        A measurement or reference containing NaN/inf yields a safe command (gravity compensation from
        the last valid state, or zero torque) with :attr:`Command.fault` naming the bad signal; the
        observer is frozen for that tick. No NaN torque ever leaves this method.
        """
        t, q, dq, tau_m, wrench, gravity = measurement
        q_d, dq_d, ddq_d = reference
        if q.shape != (self.n,) or dq.shape != (self.n,) or tau_m.shape != (self.n,) or wrench.shape != (6,):
            raise ConfigError(
                f"measurement shapes must be q, dq, tau_m ({self.n},) and wrench (6,); got "
                f"{np.shape(q)}, {np.shape(dq)}, {np.shape(tau_m)}, {np.shape(wrench)}"
            )
        model = self._model
        gv = self._gravity
        if gravity[0] != gv[0] or gravity[1] != gv[1] or gravity[2] != gv[2]:
            if not math.isfinite(gravity[0] + gravity[1] + gravity[2]):
                return self._fault(measurement, reference)
            gv[:] = gravity
            model.gravity.linear = gv

        g = pin.computeGeneralizedGravity(model, self._data_g, q)
        C = pin.computeCoriolisMatrix(model, self._data_c, q, dq)
        p = pin.rnea(self._model0, self._data_p, q, self._zeros, dq)  # M(q) dq
        ff = self.impedance.compute_feedforward(q_d, ddq_d)  # M(q_d) ddq_d
        J = (
            pin.computeFrameJacobian(model, self._data_j, q, self._sensor_id, pin.LOCAL)
            if self.kappa_ext
            else self._zeros6n
        )
        flags = self._flags
        if not self._started:  # p(0): the integral of (4) starts here, nothing to integrate yet
            if not math.isfinite(sum(p.tolist())):
                return self._fault(measurement, reference)
            self.observer.reset(p)
            if self.detection_observer is not None:
                self.detection_observer.reset(p)
            flags[_k.INTEGRATE] = 0.0
        else:
            flags[_k.INTEGRATE] = 1.0
        # bumpless kappa_eps ramp
        w = self._eps_weight
        if w != self.kappa_eps:
            inc = self.dt / self.switch_time
            w = min(w + inc, 1.0) if self.kappa_eps > w else max(w - inc, 0.0)
            self._eps_weight = w
        flags[_k.EPS_WEIGHT] = w
        flags[_k.KAPPA_F] = self.kappa_f
        flags[_k.KAPPA_EXT] = self.kappa_ext
        gravity_mode = self.reacted and self.reaction == "gravity"
        flags[_k.GRAVITY_MODE] = gravity_mode
        if not gravity_mode:
            self.impedance.maybe_update_damping(q)
        tau = self._tau
        status = _k.controller_tick(
            q, dq, tau_m, wrench, q_d, dq_d, g, C, p, ff, J, self.impedance.damping,
            self._gains, self._obs, flags, tau, self._over,
        )  # fmt: skip
        if status < 0:
            return self._fault(measurement, reference)
        self._started = True

        collided: tuple[int, ...] = ()
        detected = False
        if self.detector is not None:
            if status > 0:
                collided = tuple(np.flatnonzero(self._over).tolist())
                self.detector.record(collided, t)
                if not self.reacted and self.reaction != "none":
                    self.reacted = True
                    if self.reaction == "compliant":
                        self._kappa_eps_before_reaction = self.kappa_eps
                        self.set_switches(kappa_eps=0)
            detected = self.detector.detected
        self._last_q[:] = q
        self._has_last_q = True
        self.last_fault = ""
        return Command(tau.copy(), self.detection_residual.copy(), detected, collided, self.mode, "")

    def _fault(self, measurement: Measurement, reference: Reference) -> Command:
        """Name what is wrong with this tick's inputs and return the safe command."""
        named = [
            (f"measurement {name}", v)
            for name, v in zip(("q", "dq", "tau_m", "wrench", "gravity"), measurement[1:], strict=True)
        ] + [(f"reference {name}", v) for name, v in zip(("q_d", "dq_d", "ddq_d"), reference, strict=True)]
        bad = [name for name, v in named if not np.all(np.isfinite(v))]
        return self._safe_command("non-finite " + ", ".join(bad) if bad else "non-finite model terms")
