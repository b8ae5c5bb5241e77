"""Controller: impedance control (2) + momentum observer (4)-(6) + collision detection (12) and reaction (13).

One object behind ``step(measurement, reference) -> Command``. The tick runs in the C++ core
(``reflexarm._core``, ``cpp/src/controller.cpp``): one call per tick evaluates the dynamics terms once and
shares them between the control law and the observer(s), checks the input contract and bounds the torque.
This class is the Python face of that core: it validates the parameters, converts inputs of other types and
builds the :class:`~reflexarm.signals.Command`.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_positive_scalar, as_switch, as_vector
from reflexarm.control._core_params import core_params
from reflexarm.control._setup import (
    check_detection_friction,
    check_discretization,
    check_period_band,
    load_core,
    resolve_torque_limit,
    warn_slow_detector,
)
from reflexarm.control.collision.classify import SIGNIFICANCE_SHARE, contact_geometry_args, controller_geometry
from reflexarm.control.collision.detect import CollisionDetector
from reflexarm.control.collision.event import CollisionEvent
from reflexarm.control.collision.react import REACTIONS, ReactionSettings, check_reactions
from reflexarm.control.contract import (
    BAD_SHAPE,
    InputBounds,
    TimingStats,
    _as_time,
    convert_inputs,
    shape_error,
    signal_bounds,
    timing_stats,
)
from reflexarm.control.impedance import JointImpedanceController
from reflexarm.control.law_stability import warn_if_unstable
from reflexarm.control.momentum_observer import MomentumObserver
from reflexarm.errors import ConfigError
from reflexarm.robots.collision_geometry import CollisionGeometry
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Command, Measurement, Reference

__all__ = ["MODES", "OBSERVER_DISCRETIZATIONS", "REACTIONS", "Controller"]

#: Observer discretizations: the paper's explicit Euler (stable for observer_gain * dt < 1), or the first-order
#: filter's exact form (stable at any gain).
OBSERVER_DISCRETIZATIONS = ("euler", "exact")

#: Mode names reported in :attr:`Command.mode`.
MODES = (
    "compliant",  # kappa_eps = 0: closed loop (3)
    "precise_stiff",  # kappa_eps = 1, kappa_ext = 0: closed loop (10)
    "precise_ee_compliant",  # kappa_eps = kappa_ext = 1: closed loop (11)
    "gravity_compensation",  # reaction (13)
    "fault",  # unusable input or invalid observer: safe command
    "braking",  # reaction "brake": damping injection until the arm rests
    "retracting",  # reaction "retract": moving the contact away
    "holding",  # after brake / retract: holding a posture
)


class Controller:
    """Joint impedance controller with momentum observer, disturbance compensation and collision handling.

    **The input contract of** :meth:`step` (checked in this order, before any state changes):

    1. *Type and shape* (programming errors, raised as :class:`~reflexarm.errors.SignalError` naming the
       signal): ``measurement`` unpacks to ``(t, q, dq, tau_m, wrench, gravity)`` and ``reference`` to
       ``(q_d, dq_d, ddq_d)``; t is a real number; q, dq, tau_m, q_d, dq_d, ddq_d have shape (n,), wrench
       (6,), gravity (3,); values are real (integer or floating dtypes, lists of numbers). Complex, bool,
       str and object values raise. C-contiguous float64 arrays (read-only or not) and a float or
       ``numpy.float64`` t go straight into the C++ tick, read in place; anything else is converted once to
       contiguous float64 first (some 10-20 us more). The Command's arrays are new ones each tick (keep them).
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

    **One implementation.** The tick (contract, dynamics terms, observers, detection, law, bounds, reaction)
    runs in the C++ core ``reflexarm._core`` (``cpp/``, :class:`reflexarm::Controller`, the class a C++ or
    ros2_control loop uses); this class checks the construction parameters, converts inputs that are not
    float64 arrays and turns the core's result into a :class:`Command`. Fault codes and signal ids are those
    of :mod:`reflexarm.control.contract`.

    Args:
        robot: the controller's model (M_hat, C_hat, g_hat, tau_f_hat, Jacobian of the wrist sensor
            frame, joint/velocity/effort limits); a private copy is kept.
        stiffness: K [Nm/rad], positive, scalar or (n,); one whose law is unstable at ``dt`` gives an
            UnstableLawWarning naming the joint and a stiffness that would do (:mod:`reflexarm.control.law_stability`).
        damping_ratio: modal damping D_xi [-], scalar or (n,).
        observer_gain: K_o [1/s] of the observer used for compensation and detection.
        detection_observer_gain: if given, a second, usually faster observer with this gain runs in
            parallel and is the one used for detection (the paper's proposal at the end of Sec. III-A);
            the first observer is then used for compensation only.
        detection_kappa_f: 1: the detection observer subtracts the friction model in (6) whatever ``kappa_f``
            (the law and the compensating observer keep theirs); 0 (default, the paper's): it follows
            ``kappa_f``. Needs ``detection_observer_gain``. A joint that slides into a contact then shows the
            contact, not the contact less its friction.
        detection_friction_velocity_band: that friction model's velocity band [rad/s] (``None``: the
            model's); wider than the velocity noise keeps noise from flipping its Coulomb term.
        detection_filter_gain: K_f [1/s], scalar or (n,): the detector looks at the detection residual filtered
            once more, r_f += (1 - e^{-K_f h}) (r - r_f) (exact at any K_f), a second-order filter of the
            external torque with poles -K_o,det and -K_f (the second-order observer of Haddadin et al., T-RO
            2017, with real poles): about half the noise at the same ramp lag, so lower levels and an earlier
            detection. ``Command.residual`` is then r_f. ``None`` (default): the paper's first order.
        threshold: zeta [Nm] per joint for collision detection (12); ``None`` disables detection.
        reaction: what a detected collision the wrist sensor does not measure does: ``"gravity"`` (13),
            ``"brake"``, ``"retract"``, ``"compliant"`` or ``"none"`` (see
            :mod:`reflexarm.control.collision.react`). Reactions latch until :meth:`reset`; detection goes on
            while they run (:attr:`event` counts re-contacts).
        contact_reaction: the same for a detection while the wrist sensor measures more than
            ``reaction_settings.contact_level`` (an end-effector contact; only with kappa_ext = 0, since with
            kappa_ext = 1 the residual excludes what the sensor measures); ``None``: as ``reaction``.
        reaction_settings: :class:`~reflexarm.control.collision.ReactionSettings` (brake time, retract distance,
            the guard's rest level, the contact level, ...); default: its defaults.
        contact_geometry: the links' collision surfaces for isolating a detected collision inside the tick
            (:class:`~reflexarm.robots.CollisionGeometry`); ``"auto"`` (default): sampled from the robot file at
            :data:`~reflexarm.control.collision.classify.CONTROLLER_SPACING` (once per file; none for a model
            built in memory, and none without a threshold); ``None``: no isolation (:attr:`event`'s estimate is
            then the wrist sensor's for measured contacts only).
        isolation_share: residual components above this share of the threshold count for isolation.
        observer_discretization: ``"euler"`` (the paper's explicit Euler of (4); needs observer_gain * dt *
            period_band[1] < 1) or ``"exact"`` (the first-order filter's exact form over the measured period:
            stable at any gain, e.g. K_o = 500 1/s at 100 Hz).
        kappa_f: friction compensation in (2) and in the observer (6) (0/1).
        kappa_eps: disturbance compensation in (2) (0/1).
        kappa_ext: wrist-wrench term in the observer (6), "EFC" (0/1).
        residual_limit: cut-off of the observer output used for compensation [Nm] (paper: 30).
        switch_time: kappa_eps changes are ramped linearly over this time [s] so that a switch causes
            no torque jump (bumpless); 0 switches at once.
        dt: nominal control period [s] (default 1 kHz).
        damping_update_period: recompute D from M(q) every this many accepted ticks (1 = every tick). The
            core spreads one computation over min(4, damping_update_period) ticks (factorization,
            eigenvectors in steps, assembly) so that no tick carries it whole: the new D is used from that
            many ticks - 1 after the M(q) it comes from (3 ms at the default 10 and 1 kHz); the first tick
            after construction or :meth:`reset` computes it whole.
        torque_limit: saturation of the command [Nm]: ``"model"`` (default) the model's effort limits
            (joints without a finite positive one are not saturated, with a warning naming them); a
            scalar or (n,) positive array; or ``None`` for no saturation.
        torque_rate_limit: largest change of the command [Nm/s] (scalar or (n,)), or ``None`` (default).
        input_bounds: the plausibility bounds (:class:`InputBounds`; default: its defaults).
        period_band: (low, high) multiples of ``dt`` the integrated period is clipped to; with the Euler
            observer ``observer_gain * dt * high`` must stay below 1.
    """

    def __init__(
        self,
        robot: RobotModel,
        *,
        stiffness: npt.ArrayLike = 300.0,
        damping_ratio: npt.ArrayLike = 0.7,
        observer_gain: npt.ArrayLike = 5.0,
        detection_observer_gain: npt.ArrayLike | None = None,
        detection_kappa_f: int = 0,
        detection_friction_velocity_band: float | None = None,
        detection_filter_gain: npt.ArrayLike | None = None,
        threshold: npt.ArrayLike | None = 11.0,
        reaction: str = "gravity",
        contact_reaction: str | None = None,
        reaction_settings: ReactionSettings | None = None,
        observer_discretization: str = "euler",
        contact_geometry: CollisionGeometry | str | None = "auto",
        isolation_share: float = SIGNIFICANCE_SHARE,
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
        self._init_kwargs = {k: v for k, v in locals().items() if k not in ("self", "robot")}  # for copies
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
        warn_if_unstable(self.robot, self.impedance.stiffness, self.impedance.damping_ratio, self.dt)
        self.n = n
        # the observers validate their gains here; below they are rebuilt on the core's state
        euler = check_discretization(observer_discretization, OBSERVER_DISCRETIZATIONS) == "euler"
        self.observer = MomentumObserver(n, observer_gain, self.dt, _euler=euler)
        self.detection_observer = (
            None
            if detection_observer_gain is None
            else MomentumObserver(n, detection_observer_gain, self.dt, _euler=euler)
        )
        self.detection_kappa_f, self.detection_friction_velocity_band = check_detection_friction(
            detection_kappa_f, detection_friction_velocity_band, self.detection_observer is not None
        )
        self.detection_filter_gain = (
            None
            if detection_filter_gain is None
            else as_vector(detection_filter_gain, n, "detection_filter_gain", positive=True)
        )
        self.detector = None if threshold is None else CollisionDetector(n, threshold)
        if self.detector is not None:  # a detector so slow that it is practically off says so
            detecting = self.observer if self.detection_observer is None else self.detection_observer
            warn_slow_detector(detecting.observer_gain, self.detection_filter_gain, self.robot.joint_names)
        self.reaction, self.contact_reaction, self.reaction_settings = check_reactions(
            reaction, contact_reaction, reaction_settings
        )
        self.observer_discretization = observer_discretization
        self._kappa_init = (
            as_switch(kappa_f, "kappa_f"),
            as_switch(kappa_eps, "kappa_eps"),
            as_switch(kappa_ext, "kappa_ext"),
        )
        self._check_limits(residual_limit, switch_time, period_band, input_bounds, torque_limit, torque_rate_limit)
        self._bind_core(contact_geometry, isolation_share, euler)

    def _check_limits(
        self,
        residual_limit: float,
        switch_time: float,
        period_band: tuple[float, float],
        input_bounds: InputBounds | None,
        torque_limit: npt.ArrayLike | str | None,
        torque_rate_limit: npt.ArrayLike | None,
    ) -> None:
        """The construction's limits and bands, checked (ConfigError naming the argument)."""
        self.residual_limit = as_positive_scalar(residual_limit, "residual_limit")
        if not (isinstance(switch_time, (int, float)) and math.isfinite(switch_time) and switch_time >= 0):
            raise ConfigError(f"switch_time must be a non-negative number of seconds; got {switch_time!r}")
        self.switch_time = float(switch_time)
        gains = [self.observer.observer_gain]
        if self.detection_observer is not None:
            gains.append(self.detection_observer.observer_gain)
        exact = self.observer_discretization == "exact"
        self.period_band = check_period_band(period_band, self.dt, gains, exact=exact)
        self.input_bounds = InputBounds() if input_bounds is None else input_bounds
        if not isinstance(self.input_bounds, InputBounds):
            raise ConfigError(f"input_bounds must be an InputBounds; got {type(input_bounds).__name__}")
        self.torque_limit = resolve_torque_limit(self.robot, torque_limit)
        self.torque_rate_limit = (
            None
            if torque_rate_limit is None
            else as_vector(torque_rate_limit, self.n, "torque_rate_limit", positive=True)
        )

    def _bind_core(self, contact_geometry: CollisionGeometry | str | None, isolation_share: float, euler: bool) -> None:
        """The C++ core configured with the checked settings, and the Python views onto its state."""
        n = self.n
        core = load_core()
        try:  # the model crosses as text (a Boost.Python pin.Model cannot be passed to nanobind)
            self._core = c = core.Controller(self.robot.pin_model.saveToString(), core_params(self, core))
        except ValueError as e:  # the core's ConfigError: the checks above should have caught it
            raise ConfigError(f"the C++ core refused the controller's parameters: {e}") from e
        self.contact_geometry = self._set_contact_geometry(contact_geometry, isolation_share)
        views = c.observer_arrays  # live, writable views of the core's observer states
        self.observer = MomentumObserver(n, self.observer.observer_gain, self.dt, _state=views[:3], _euler=euler)
        if self.detection_observer is not None:
            gain = self.detection_observer.observer_gain
            self.detection_observer = MomentumObserver(n, gain, self.dt, _state=views[3:], _euler=euler)
        self.impedance.damping = c.damping  # read-only live view of the damping matrix the tick uses
        self._update = c.update
        c.set_command_type(Command)
        self._step = c.step  # returns the Command of a plain tick, else the status
        self._step_signals = c.step_signals  # the same from (measurement, reference); None for other types
        self._tau, self._residual, self._saturated, self._collided = c.tau, c.residual, c.saturated, c.collided
        self._sat_shift = int(core.SAT_SHIFT)
        self._g_norm = float(np.linalg.norm(self.robot.pin_model.gravity.linear))
        self._mode: str = c.mode

    def _set_contact_geometry(self, geometry: CollisionGeometry | str | None, share: float) -> CollisionGeometry | None:
        """Hand the links' surfaces to the core (isolation in the tick); the geometry used, or None."""
        if not (isinstance(share, (int, float)) and 0.0 < share <= 1.0):
            raise ConfigError(f"isolation_share must be in (0, 1]; got {share!r}")
        self.isolation_share = float(share)
        if geometry is None or self.detector is None:
            return None
        if isinstance(geometry, str):
            if geometry != "auto":
                raise ConfigError(f"contact_geometry must be 'auto', None or a CollisionGeometry; got {geometry!r}")
            geometry = controller_geometry(self.robot)
            if geometry is None:
                return None
        if not isinstance(geometry, CollisionGeometry) or geometry.n != self.n:
            raise ConfigError(
                f"contact_geometry must be a CollisionGeometry of this robot's {self.n} links; got {geometry!r}"
            )
        self._core.set_contact_geometry(*contact_geometry_args(geometry, share))
        return geometry

    # ------------------------------------------------------------------ copies
    def __copy__(self) -> Controller:
        """An independent controller in the same state: the same settings, the C++ core's whole state copied (a
        shallow copy would share the core, so that stepping one would step both)."""
        twin = Controller(self.robot, **self._init_kwargs)
        twin._core.copy_state_from(self._core)
        twin.detector = copy.deepcopy(self.detector)
        if twin.detector is not None:
            twin.detector.threshold = twin.detector.threshold.copy()
        twin.impedance.kappa_f = twin.kappa_f
        twin._mode = self._mode
        return twin

    def __deepcopy__(self, memo: dict[int, object]) -> Controller:
        return self.__copy__()  # as __copy__: the copy owns everything (its model, core and detector)

    # ------------------------------------------------------------------ run-time switches and facts
    def set_switches(
        self, *, kappa_f: int | None = None, kappa_eps: int | None = None, kappa_ext: int | None = None
    ) -> None:
        """Flip kappa_f / kappa_eps / kappa_ext at run time (kappa_eps is ramped over ``switch_time``).

        kappa_ext only enters the observer's integrand (6), so flipping it moves the residual continuously.
        """
        values = [-1 if v is None else as_switch(v, name) for v, name in
                  ((kappa_f, "kappa_f"), (kappa_eps, "kappa_eps"), (kappa_ext, "kappa_ext"))]  # fmt: skip
        self._core.set_switches(*values)
        self.impedance.kappa_f = self.kappa_f
        self._mode = self._core.mode

    @property
    def kappa_f(self) -> int:
        """Friction compensation switch in (2) and (6) (0/1)."""
        return int(self._core.kappa_f)

    @property
    def kappa_eps(self) -> int:
        """Disturbance compensation switch in (2) (0/1; the applied weight ramps over ``switch_time``)."""
        return int(self._core.kappa_eps)

    @property
    def kappa_ext(self) -> int:
        """Wrist-wrench term in the observer (6), "EFC" (0/1)."""
        return int(self._core.kappa_ext)

    @property
    def reacted(self) -> bool:
        """True once a detected collision triggered the reaction (latched until :meth:`reset`)."""
        return bool(self._core.reacted)

    @property
    def event(self) -> CollisionEvent | None:
        """The record of the collision detected since the last :meth:`reset` (None before a detection):
        when, which joints, class, reaction and its phase, energies, the guard's report."""
        return CollisionEvent.from_core(self._core.event, geometry=self.contact_geometry, robot=self.robot)

    @property
    def mode(self) -> str:
        """Active mode name (see :data:`MODES`; ``"fault"`` appears only in commands)."""
        return str(self._core.mode)

    @property
    def detection_residual(self) -> np.ndarray:
        """The residual the detector looks at: the detection observer's (else the observer's), through the second
        stage when there is one (``detection_filter_gain``); a live view of the core's state (copy it to keep it)."""
        return np.asarray(self._core.detection_residual)

    @property
    def damping(self) -> np.ndarray:
        """The damping matrix D of (2) the tick uses now (read-only live view)."""
        return np.asarray(self._core.damping)

    @property
    def timing(self) -> TimingStats:
        """Measured control periods since the last :meth:`reset` (see :class:`TimingStats`)."""
        return timing_stats(self._core.timing)

    @property
    def signal_bounds(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The plausibility bounds per signal as (low, high) arrays (copies)."""
        return signal_bounds(self._core.bounds, self.input_bounds, self._g_norm)

    @property
    def observer_state(self) -> np.ndarray:
        """Copy of both observers' states (6, n): integral, p(0), residual of the compensation observer,
        then of the detection observer (zeros when there is none). A rejected tick leaves it unchanged."""
        return np.array(self._core.observer_arrays)

    @property
    def last_fault(self) -> str:
        """The fault text of the last tick ("" after an accepted tick and after :meth:`reset`)."""
        return str(self._core.fault)

    @property
    def observer_invalid(self) -> bool:
        """True once the observer state became invalid (latched until :meth:`reset`)."""
        return bool(self._core.observer_invalid)

    def reset(self) -> None:
        """Clear observer states, the latched collision, reaction and observer fault, the clock and its
        statistics; the next step re-initialises.

        After a ``"compliant"`` reaction the kappa_eps active before it is restored. The last command is kept (a
        torque rate limit goes on from it); everything else is as after construction: without a rate limit a run
        after ``reset()`` equals a fresh controller's bitwise.
        """
        self._core.reset()
        if self.detector is not None:
            self.detector.reset()
        self.impedance.reset()
        self._mode = self._core.mode

    # ------------------------------------------------------------------ the tick
    def step(self, measurement: Measurement, reference: Reference) -> Command:
        """One control tick: eq. (2) with the observer (4)-(6), detection (12) and reaction (13).

        Inputs are checked against the contract of the class docstring before any state changes. A bad
        value gives the safe command with :attr:`Command.fault` naming the signal and the bound; a wrong
        type or shape raises :class:`~reflexarm.errors.SignalError`. No NaN torque and no torque beyond
        ``torque_limit`` ever leaves this method.
        """
        out = self._step_signals(measurement, reference)  # the Command, a status int, or None: other types
        if out.__class__ is int:  # threshold crossings, a bounded torque or a fault
            return self._finish(out, measurement[0])
        if out is None:
            return self._step_unpacked(measurement, reference)
        return out  # type: ignore[no-any-return]

    def _step_unpacked(self, measurement: Measurement, reference: Reference) -> Command:
        """The tick for inputs the core's ``step_signals`` does not read (not tuples, t not a float, vectors
        that are not float64 buffers): unpacked here, converted once if needed, or SignalError."""
        try:
            t, q, dq, tau_m, wrench, gravity = measurement
            q_d, dq_d, ddq_d = reference
            if t.__class__ is not float:
                t = _as_time(t)
            out = self._step(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d)
        except (TypeError, ValueError):  # not contiguous float64 vectors (or not unpackable): convert or raise
            return self._step_converted(measurement, reference)
        if out.__class__ is int:
            return self._finish(out, t)
        return out  # type: ignore[no-any-return]

    def _step_converted(self, measurement: Measurement, reference: Reference) -> Command:
        """The tick for inputs that are not all contiguous float64 arrays: convert them once (or raise
        SignalError naming the signal)."""
        args, _ = convert_inputs(measurement, reference, self.n)
        return self._finish(self._update(*args), args[0])

    def _finish(self, status: int, t: float) -> Command:
        """The Command of a tick from the core's status: a fault (< 0), or n_over + (n_saturated << SAT_SHIFT)."""
        if status < 0:
            return self._reject(status)
        shift = self._sat_shift
        n_over = status & ((1 << shift) - 1)
        n_sat = status >> shift
        saturated = tuple(np.flatnonzero(self._saturated).tolist()) if n_sat else ()
        collided: tuple[int, ...] = ()
        detected = False
        if self.detector is not None:
            if n_over:
                collided = tuple(np.flatnonzero(self._collided).tolist())
                self.detector.record(collided, float(t))
                self._mode = self._core.mode  # the reaction may have switched it
            detected = self.detector.detected
        mode = self._core.command_mode  # a reaction may change it on any tick (brake -> hold)
        return Command(self._tau.copy(), self._residual.copy(), detected, collided, mode, "", saturated)

    def _reject(self, code: int) -> Command:
        """The safe command the core computed for a rejected tick (a wrong shape raises SignalError)."""
        c = self._core
        if code == BAD_SHAPE:
            signal, _, received, _, expected = c.fault_info
            raise shape_error(signal, int(received), int(expected))
        fault = c.fault
        saturated = tuple(np.flatnonzero(self._saturated).tolist())
        return Command(self._tau.copy(), self._residual.copy(), bool(c.collision), (), "fault", fault, saturated, code)
