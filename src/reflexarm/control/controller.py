"""Controller: impedance control (2) + momentum observer (4)-(6) + collision detection (12) and reaction (13).

One object behind ``step(measurement, reference) -> Command``. The dynamics terms are evaluated once per
tick and shared by the control law and the observer(s); the input contract, the observers, the control
law and the torque bounds run in one compiled pass (:mod:`reflexarm.control._kernels`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from reflexarm._validation import as_positive_scalar, as_switch, as_vector
from reflexarm.control import _kernels as _k
from reflexarm.control._setup import check_period_band, fill_work, resolve_torque_limit
from reflexarm.control.collision import CollisionDetector
from reflexarm.control.contract import (
    InputBounds,
    TimingStats,
    convert_inputs,
    describe_fault,
    shape_error,
    signal_bounds,
    timing_stats,
)
from reflexarm.control.impedance import JointImpedanceController
from reflexarm.control.momentum_observer import MomentumObserver
from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Command, Measurement, Reference

__all__ = ["MODES", "REACTIONS", "Controller"]

_F64 = np.dtype(np.float64)

#: Reactions to a detected collision: eq. (13) gravity compensation; switch to the compliant mode
#: (kappa_eps = 0, Fig. 3); or none (detection is reported only).
REACTIONS = ("gravity", "compliant", "none")

#: Mode names reported in :attr:`Command.mode`.
MODES = (
    "compliant",  # kappa_eps = 0: closed loop (3)
    "precise_stiff",  # kappa_eps = 1, kappa_ext = 0: closed loop (10)
    "precise_ee_compliant",  # kappa_eps = kappa_ext = 1: closed loop (11)
    "gravity_compensation",  # reaction (13)
    "fault",  # unusable input or invalid observer: safe command
)


class Controller:
    """Joint impedance controller with momentum observer, disturbance compensation and collision handling.

    **The input contract of** :meth:`step` (checked in this order, before any state changes):

    1. *Type and shape* (programming errors, raised as :class:`~reflexarm.errors.SignalError` naming the
       signal): ``measurement`` unpacks to ``(t, q, dq, tau_m, wrench, gravity)`` and ``reference`` to
       ``(q_d, dq_d, ddq_d)``; t is a real number; q, dq, tau_m, q_d, dq_d, ddq_d have shape (n,), wrench
       (6,), gravity (3,); values are real (integer or floating dtypes, lists of numbers). Complex, bool,
       str and object values raise. Float64 arrays go straight into the compiled tick; anything else is
       converted once to contiguous float64 first (some 10-20 us more, never a recompilation).
    2. *Values* (run-time faults: the tick returns the **safe command**, ``Command.mode == "fault"``,
       ``Command.fault`` naming the signal, the component, the value and the bound, ``fault_code`` one of
       :data:`~reflexarm.control.contract.FAULT_CODES`): t finite and strictly later than the last accepted
       stamp; every component finite; q and q_d within the joint limits +- ``position_margin``; |dq| and
       |dq_d| <= ``velocity_factor`` x velocity limit; |tau_m| <= ``torque_factor`` x torque limit; wrist
       force/moment components <= ``max_force``/``max_moment``; | |gravity| - |model gravity| | <=
       ``gravity_tolerance``; |ddq_d| <= ``max_acceleration`` (all :class:`InputBounds`, readable per joint
       in :attr:`signal_bounds`); the model's terms at this state finite and M(q) positive definite on a
       damping-update tick.
    3. A rejected tick changes nothing: observers, damping matrix, last accepted time and position, the
       model's gravity and the detector are exactly as before it. The safe command is gravity compensation
       at the last accepted position (zero torque before the first), bounded like every command.

    **Recovery.** A measurement or reference fault lasts one tick: the next valid tick is controlled
    normally (the observer then integrates the period since the last accepted stamp, clipped to the band).
    An *invalid observer* (a non-finite state or control law, which the bounds above make unreachable) latches:
    every command is then the safe command with ``fault`` saying detection is off and ``collision=True``
    (an invalid residual never reports "no collision") until :meth:`reset`, as a robot needs an explicit
    error recovery after a reflex.

    **Bounded torque.** Every command (control law, reaction and safe command) is limited per joint to
    +-``torque_limit``; with ``torque_rate_limit`` its change per tick is limited to
    ``torque_rate_limit * dt`` as well (not on the first command after construction). Joints limited this
    tick are listed in :attr:`Command.saturated`.

    **Time.** The observer integrates the measured period ``t - t_last_accepted`` clipped to
    ``[period_band[0] * dt, period_band[1] * dt]``; :attr:`timing` reports the periods seen.

    The bounds, the state and the fault codes are plain data (one float64 array and integer codes, see
    :mod:`reflexarm.control._kernels`), so the same contract carries over to a compiled C++ tick.

    Args:
        robot: the controller's model (M_hat, C_hat, g_hat, tau_f_hat, Jacobian of the wrist sensor
            frame, joint/velocity/effort limits); a private copy is kept.
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
        dt: nominal control period [s] (default 1 kHz).
        damping_update_period: see :class:`JointImpedanceController`.
        torque_limit: saturation of the command [Nm]: ``"model"`` (default) the model's effort limits
            (joints without a finite positive one are not saturated, with a warning naming them); a
            scalar or (n,) positive array; or ``None`` for no saturation.
        torque_rate_limit: largest change of the command [Nm/s] (scalar or (n,)), or ``None`` (default).
        input_bounds: the plausibility bounds (:class:`InputBounds`; default: its defaults).
        period_band: (low, high) multiples of ``dt`` the integrated period is clipped to;
            ``observer_gain * dt * high`` must stay below 1.
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
        torque_limit: npt.ArrayLike | str | None = "model",
        torque_rate_limit: npt.ArrayLike | None = None,
        input_bounds: InputBounds | None = None,
        period_band: tuple[float, float] = (0.5, 2.0),
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
        # all parameters and state of the compiled tick live in one array (see control/_kernels.py)
        self._work = w = np.zeros(_k.layout_size(n))
        self._rows = rows = w[_k.N_HEADER : _k.N_HEADER + _k.N_ROWS * n].reshape(_k.N_ROWS, n)
        self._mats = w[_k.N_HEADER + _k.N_ROWS * n :].reshape(_k.N_MATS, n, n)
        self.observer = MomentumObserver(n, observer_gain, self.dt, _state=rows[_k.INT_ROW : _k.INT_ROW + 3])
        self.detection_observer = (
            None
            if detection_observer_gain is None
            else MomentumObserver(n, detection_observer_gain, self.dt, _state=rows[_k.INT_DET_ROW : _k.INT_DET_ROW + 3])
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
        gains = [self.observer.observer_gain]
        if self.detection_observer is not None:
            gains.append(self.detection_observer.observer_gain)
        self.period_band = check_period_band(period_band, self.dt, gains)
        self.input_bounds = InputBounds() if input_bounds is None else input_bounds
        if not isinstance(self.input_bounds, InputBounds):
            raise ConfigError(f"input_bounds must be an InputBounds; got {type(input_bounds).__name__}")
        self.torque_limit = resolve_torque_limit(self.robot, torque_limit)
        self.torque_rate_limit = (
            None if torque_rate_limit is None else as_vector(torque_rate_limit, n, "torque_rate_limit", positive=True)
        )
        self._eps_weight = float(self.kappa_eps)  # ramped kappa_eps actually applied
        self._kappa_eps_before_reaction = self.kappa_eps

        model = self.robot.pin_model
        self._model = model
        self._data_g, self._data_c, self._data_j, self._data_m = (model.createData() for _ in range(4))
        self._model0 = self.impedance.model_no_gravity  # M(q) x as a zero-gravity RNEA
        self._data_p, self._data_ff = self._model0.createData(), self._model0.createData()
        self._sensor_id = self.robot.sensor_frame_id
        self._zeros = np.zeros(n)
        self._zeros6n = np.zeros((6, n))
        # joint springs of the robot file (Pinocchio has none): g_hat(q) includes K_s (q - q_s)
        self._has_springs = self.robot.has_springs
        self._spring_k, self._spring_q = self.robot.spring_stiffness, self.robot.spring_reference
        self._spring = np.zeros(n)
        self._M = self._mats[_k.M_MAT]
        self.impedance.damping = self._mats[_k.D_MAT]  # one damping matrix, updated by the tick
        self._gravity = np.asarray(model.gravity.linear, dtype=float).copy()  # last accepted
        self._gravity_in_model = self._gravity.copy()  # what the model holds now (may be a candidate)
        self._gravity_staged = False
        self._damping_countdown = 0
        self._damping_period = self.impedance.damping_update_period
        self._converting = False
        self._fast = False  # the first tick checks the input types (then: float64 arrays go straight in)
        _k.warm_up()
        self._tau_out = self._rows[_k.TAU_ROW]  # the last command sent
        self._r_det = self.detection_residual
        self.reacted = False
        self.last_fault = ""
        fill_work(self)
        self._set_switch_flags()
        self._update_mode()

    def _set_switch_flags(self) -> None:
        w = self._work
        w[_k.KAPPA_F] = self.kappa_f
        w[_k.KAPPA_EXT] = self.kappa_ext
        w[_k.EPS_WEIGHT] = self._eps_weight
        self._gravity_mode = self.reacted and self.reaction == "gravity"
        w[_k.GRAVITY_MODE] = float(self._gravity_mode)

    def _update_mode(self) -> None:
        if self.reacted and self.reaction == "gravity":
            self._mode = "gravity_compensation"
        elif not self.kappa_eps:
            self._mode = "compliant"
        else:
            self._mode = "precise_ee_compliant" if self.kappa_ext else "precise_stiff"
        self._set_switch_flags()

    # ------------------------------------------------------------------ run-time switches and facts
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
        self._update_mode()

    @property
    def mode(self) -> str:
        """Active mode name (see :data:`MODES`; ``"fault"`` appears only in commands)."""
        return self._mode

    @property
    def detection_residual(self) -> np.ndarray:
        """The residual the detector looks at."""
        return (self.detection_observer or self.observer).residual

    @property
    def timing(self) -> TimingStats:
        """Measured control periods since the last :meth:`reset` (see :class:`TimingStats`)."""
        return timing_stats(self._work)

    @property
    def signal_bounds(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The plausibility bounds per signal as (low, high) arrays (copies)."""
        return signal_bounds(self._work, self._rows)

    @property
    def observer_state(self) -> np.ndarray:
        """Copy of both observers' states (6, n): integral, p(0), residual of the compensation observer,
        then of the detection observer (zeros when there is none). A rejected tick leaves it unchanged."""
        return self._rows[_k.INT_ROW : _k.R_DET_ROW + 1].copy()

    @property
    def observer_invalid(self) -> bool:
        """True once the observer state became invalid (latched until :meth:`reset`)."""
        return bool(self._work[_k.OBS_INVALID])

    def reset(self) -> None:
        """Clear observer states, the latched collision, reaction and observer fault, the clock and its
        statistics; the next step re-initialises.

        After a ``"compliant"`` reaction the kappa_eps active before it is restored.
        """
        if self.reacted and self.reaction == "compliant":
            self.kappa_eps = self._kappa_eps_before_reaction
        self.reacted = False
        self.last_fault = ""
        self.observer.reset()
        if self.detection_observer is not None:
            self.detection_observer.reset()
        if self.detector is not None:
            self.detector.reset()
        self.impedance.reset()
        self._damping_countdown = 0
        w = self._work
        for key in (_k.STARTED, _k.HAS_T, _k.LAST_T, _k.OBS_INVALID, _k.UPDATE_DAMPING,
                    _k.T_COUNT, _k.T_SUM, _k.T_MIN, _k.T_MAX, _k.T_CLIPPED):  # fmt: skip
            w[key] = 0.0
        self._eps_weight = float(self.kappa_eps)
        self._update_mode()

    # ------------------------------------------------------------------ the tick
    def step(self, measurement: Measurement, reference: Reference) -> Command:
        """One control tick: eq. (2) with the observer (4)-(6), detection (12) and reaction (13).

        Inputs are checked against the contract of the class docstring before any state changes. A bad
        value gives the safe command with :attr:`Command.fault` naming the signal and the bound; a wrong
        type or shape raises :class:`~reflexarm.errors.SignalError`. No NaN torque and no torque beyond
        ``torque_limit`` ever leaves this method.
        """
        if not self._fast:
            return self._step_converted(measurement, reference)
        try:
            t, q, dq, tau_m, wrench, gravity = measurement
            q_d, dq_d, ddq_d = reference
            F = _F64  # another dtype would make the compiled call fail slowly (~1 ms): convert it first
            # == not `is`: arrays made by a numba function loaded from its on-disk cache carry an unpickled
            # float64 dtype object that is equal to, but not, the np.dtype(np.float64) singleton
            if not (
                q.dtype == F and dq.dtype == F and tau_m.dtype == F and wrench.dtype == F and gravity.dtype == F
                and q_d.dtype == F and dq_d.dtype == F and ddq_d.dtype == F
            ):  # fmt: skip
                raise TypeError("not float64")  # handled below, outside this try
            gm = self._gravity_in_model
            if gravity[0] != gm[0] or gravity[1] != gm[1] or gravity[2] != gm[2]:
                gm[:] = gravity  # a candidate: restored by _reject if the tick is not accepted
                self._gravity_staged = True
                self._model.gravity.linear = gm
            model = self._model
            g = pin.computeGeneralizedGravity(model, self._data_g, q)
            if self._has_springs:
                g = g + self._spring_torque(q)
            C = pin.computeCoriolisMatrix(model, self._data_c, q, dq)
            p = pin.rnea(self._model0, self._data_p, q, self._zeros, dq)  # M(q) dq
            ff = pin.rnea(self._model0, self._data_ff, q_d, self._zeros, ddq_d)  # M(q_d) ddq_d
            J = (
                pin.computeFrameJacobian(model, self._data_j, q, self._sensor_id, pin.LOCAL)
                if self.kappa_ext
                else self._zeros6n
            )
            w = self._work
            if self._eps_weight != self.kappa_eps:  # bumpless kappa_eps ramp (committed when accepted)
                inc = self.dt / self.switch_time
                e = self._eps_weight
                w[_k.EPS_WEIGHT] = min(e + inc, 1.0) if self.kappa_eps > e else max(e - inc, 0.0)
            if self._damping_countdown == 0 and not self._gravity_mode:
                self._M[:] = pin.crba(model, self._data_m, q)  # upper triangle; the tick mirrors it
                w[_k.UPDATE_DAMPING] = 1.0
            status = _k.controller_tick(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d, g, C, p, ff, J, w)
        except Exception:  # not float64 arrays of the right shapes: convert (or raise SignalError)
            if self._converting:  # converted inputs failed as well: a genuine error, not the caller's
                raise
            self._restore_gravity()
            return self._step_converted(measurement, reference)
        if status < 0:
            return self._reject(status)
        if self._gravity_staged:
            self._gravity[:] = gm
            self._gravity_staged = False
        if self._eps_weight != self.kappa_eps:
            self._eps_weight = float(w[_k.EPS_WEIGHT])
        if not self._gravity_mode:
            self._damping_countdown = (self._damping_countdown or self._damping_period) - 1
        self.last_fault = ""
        if status == 0:
            det = self.detector
            detected = det.detected if det is not None else False
            return Command(self._tau_out.copy(), self._r_det.copy(), detected, (), self._mode, "")
        return self._with_events(status, t)

    def _step_converted(self, measurement: Measurement, reference: Reference) -> Command:
        """The tick for inputs that are not all float64 arrays: convert them once (or raise SignalError).

        Ticks with other dtypes or lists come here (about 15 us more, no compilation); after a tick of
        float64 arrays the next one takes the fast path again.
        """
        args, converted = convert_inputs(measurement, reference, self.n)
        self._fast = self._converting = True
        try:
            return self.step(Measurement(*args[:6]), Reference(*args[6:]))
        finally:
            self._converting = False
            self._fast = not converted

    def _spring_torque(self, q: np.ndarray) -> np.ndarray:
        """K_s (q - q_s) into a preallocated buffer [Nm]."""
        np.subtract(q, self._spring_q, out=self._spring)
        np.multiply(self._spring, self._spring_k, out=self._spring)
        return self._spring

    def _restore_gravity(self) -> None:
        """Put the last accepted gravity back into the model (after a candidate was not accepted)."""
        if self._gravity_staged:
            self._gravity_in_model[:] = self._gravity
            self._model.gravity.linear = self._gravity_in_model
            self._gravity_staged = False

    def _with_events(self, status: int, t: float) -> Command:
        """An accepted tick with threshold crossings and/or a bounded torque."""
        rows = self._rows
        n_over = status & ((1 << _k.SAT_SHIFT) - 1)
        saturated = tuple(np.flatnonzero(rows[_k.SAT_ROW]).tolist()) if status >> _k.SAT_SHIFT else ()
        collided: tuple[int, ...] = ()
        detected = False
        if self.detector is not None:
            if n_over:
                collided = tuple(np.flatnonzero(rows[_k.OVER_ROW]).tolist())
                self.detector.record(collided, float(t))
                if not self.reacted and self.reaction != "none":
                    self.reacted = True
                    if self.reaction == "compliant":
                        self._kappa_eps_before_reaction = self.kappa_eps
                        self.set_switches(kappa_eps=0)
                    self._update_mode()
            detected = self.detector.detected
        tau = rows[_k.TAU_ROW].copy()
        return Command(tau, self.detection_residual.copy(), detected, collided, self.mode, "", saturated)

    def _reject(self, code: int) -> Command:
        """The safe command for a rejected tick: gravity compensation at the last accepted position."""
        w, rows = self._work, self._rows
        w[_k.UPDATE_DAMPING] = 0.0
        self._restore_gravity()
        w[_k.EPS_WEIGHT] = self._eps_weight
        if code == _k.BAD_SHAPE:
            raise shape_error(w)
        fault = describe_fault(code, w)
        tau = np.zeros(self.n)
        if w[_k.HAS_LAST_Q]:
            g = pin.computeGeneralizedGravity(self._model, self._data_g, rows[_k.LAST_Q_ROW])
            if self._has_springs:
                g = g + self._spring_torque(rows[_k.LAST_Q_ROW])
            if np.all(np.isfinite(g)):
                tau[:] = g
        bounded = tau.copy()
        if w[_k.HAS_PREV_TAU]:
            prev, step = rows[_k.TAU_ROW], rows[_k.TAU_STEP_ROW]
            np.clip(bounded, prev - step, prev + step, out=bounded)
        np.clip(bounded, -rows[_k.TAU_MAX_ROW], rows[_k.TAU_MAX_ROW], out=bounded)
        saturated = tuple(np.flatnonzero(bounded != tau).tolist())
        rows[_k.TAU_ROW] = bounded
        w[_k.HAS_PREV_TAU] = 1.0
        self.last_fault = fault
        if code in (_k.OBSERVER_INVALID, _k.OUTPUT_NON_FINITE):
            collision = True  # detection is off: never report "no collision"
        else:
            collision = self.detector.detected if self.detector is not None else False
        residual = self.detection_residual.copy()
        return Command(bounded.copy(), residual, collision, (), "fault", fault, saturated, code)
