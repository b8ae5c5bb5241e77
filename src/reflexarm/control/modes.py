"""The context-sensitive control and reaction scheme of Fig. 3: named modes and a small supervisor.

Fig. 3 of the paper tabulates three settings of controller (2) with observer (4)-(6):

================================  ==========  ==========  ====================  ============
mode                              kappa_eps   kappa_ext   closed loop           use
================================  ==========  ==========  ====================  ============
``precise_ee_compliant``          1           1           (11)                  e.g. grasping: accuracy and
                                                                                end-effector compliance
``precise_stiff``                 1           0           (10)                  e.g. carrying an object of
                                                                                unknown weight
``compliant``                     0           0 (*)       (3)                   after a collision
================================  ==========  ==========  ====================  ============

(*) kappa_ext only enters the observer, which in the compliant mode is used for detection only. A mode
*selected* as ``compliant`` sets kappa_ext = 0 (the observer then sees every external torque, the
collision-detection setting of Sec. III); the *automatic* switch after a collision changes kappa_eps only
(see :class:`reflexarm.control.Controller`), so the residual the detector looks at does not jump.

:class:`ModeSupervisor` wraps a :class:`~reflexarm.control.Controller`: a task selects a mode
(:meth:`ModeSupervisor.select`, or a time :class:`ModeSchedule`), and when a link collision is detected
the controller's configured ``reaction`` takes over ("compliant": kappa_eps -> 0, ramped bumplessly;
"gravity": eq. (13)). Every change of the active mode is recorded as a :class:`ModeTransition` with its
time and cause; :meth:`ModeSupervisor.log_to` stores them in a recorded ``Trace.meta`` (the trace's
per-tick ``mode`` column shows the active mode).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from reflexarm.control.controller import Controller
from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Command, Measurement, Reference

__all__ = ["CONTROL_MODES", "ControlMode", "ModeSchedule", "ModeSupervisor", "ModeTransition"]


@dataclass(frozen=True)
class ControlMode:
    """One column of the table of Fig. 3.

    Attributes:
        name: the mode name reported in :attr:`Command.mode`.
        kappa_eps: disturbance compensation in (2) (0/1).
        kappa_ext: wrist-wrench feedback in the observer (6), "EFC" (0/1).
        closed_loop: the paper's equation of the resulting closed loop.
        accurate: Fig. 3 "Increased accuracy" (model errors compensated).
        ee_compliant: Fig. 3 "End-effector compliance".
        link_compliant: Fig. 3 "Link compliance".
    """

    name: str
    kappa_eps: int
    kappa_ext: int
    closed_loop: str
    accurate: bool
    ee_compliant: bool
    link_compliant: bool


#: The three modes of Fig. 3 with the paper's check marks, in the order of its table.
CONTROL_MODES: dict[str, ControlMode] = {
    m.name: m
    for m in (
        ControlMode("compliant", 0, 0, "(3)", accurate=False, ee_compliant=True, link_compliant=True),
        ControlMode("precise_stiff", 1, 0, "(10)", accurate=True, ee_compliant=False, link_compliant=False),
        ControlMode("precise_ee_compliant", 1, 1, "(11)", accurate=True, ee_compliant=True, link_compliant=False),
    )
}


def _mode(name: object) -> ControlMode:
    if not isinstance(name, str) or name not in CONTROL_MODES:
        raise ConfigError(f"unknown control mode {name!r}; modes are: {', '.join(CONTROL_MODES)}")
    return CONTROL_MODES[name]


@dataclass(frozen=True)
class ModeTransition:
    """A change of the active mode.

    Attributes:
        t: time of the measurement at which it took effect [s].
        from_mode: mode before (``""`` for the initial selection).
        to_mode: mode after.
        cause: ``"task"`` (selected), ``"collision"`` (reaction to a detection), ``"fault"`` (unusable
            measurement, safe command) or ``"recovered"`` (back from a fault), ``"acknowledged"`` (collision
            cleared by :meth:`ModeSupervisor.acknowledge_collision`).
        joints: joints whose residual crossed the threshold (collisions only), 0-based.
    """

    t: float
    from_mode: str
    to_mode: str
    cause: str
    joints: tuple[int, ...] = ()


class ModeSchedule:
    """Modes selected per task over time: ``[(t_start, mode), ...]``, t_start strictly increasing [s].

    The first entry must start at or before the first tick; the mode of the last entry with
    ``t_start <= t`` is the task mode at time ``t``.
    """

    def __init__(self, entries: Sequence[tuple[float, str]]) -> None:
        items = list(entries)
        if not items:
            raise ConfigError("a mode schedule needs at least one (t_start, mode) entry")
        times = []
        for entry in items:
            try:
                t, name = entry
                t = float(t)
            except (TypeError, ValueError) as e:
                raise ConfigError(f"mode schedule entries must be (t_start, mode) pairs; got {entry!r}") from e
            if not math.isfinite(t):
                raise ConfigError(f"mode schedule time must be finite; got {t!r}")
            _mode(name)
            times.append(t)
        if np.any(np.diff(times) <= 0):
            raise ConfigError(f"mode schedule times must be strictly increasing; got {times}")
        self.times = np.asarray(times)
        self.modes = tuple(name for _, name in items)

    def mode_at(self, t: float) -> str:
        """The task mode at time ``t`` (the first entry's before it starts)."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return self.modes[max(k, 0)]


class ModeSupervisor:
    """State machine of Fig. 3 around a :class:`Controller`: task modes plus the collision reaction.

    It can stand in for the controller in a control loop (``step``, ``reset``, ``mode``, ``dt``, ``n``,
    ``robot``): the runner records its :attr:`Command.mode` each tick, and :attr:`transitions` lists every
    change with its cause.

    Args:
        controller: the controller to drive. Its ``reaction`` decides what a detected collision does
            (``"compliant"``: the compliant mode of Fig. 3; ``"gravity"``: eq. (13); ``"none"``: the
            detection is logged, the mode kept). Its current kappa_eps/kappa_ext are overridden by ``mode``.
        mode: the initial task mode (a name of :data:`CONTROL_MODES`).
        schedule: optional :class:`ModeSchedule` (or a list of ``(t_start, mode)``); when given it drives
            the task mode from the measurement time and ``mode`` is ignored.

    Raises:
        ConfigError: unknown mode name (listing the modes), bad schedule.
    """

    def __init__(
        self,
        controller: Controller,
        *,
        mode: str = "precise_ee_compliant",
        schedule: ModeSchedule | Sequence[tuple[float, str]] | None = None,
    ) -> None:
        if not isinstance(controller, Controller):
            raise ConfigError(f"controller must be a reflexarm Controller; got {type(controller).__name__}")
        self.controller = controller
        if schedule is not None and not isinstance(schedule, ModeSchedule):
            schedule = ModeSchedule(schedule)
        self.schedule = schedule
        self._initial = _mode(schedule.modes[0] if schedule is not None else mode).name
        self.transitions: list[ModeTransition] = []
        self._apply(self._initial, bumpless=False)
        self._task_mode = self._initial
        self._reported = ""  # mode of the last command (for transition logging)
        self._pending_cause = "task"
        self._collision_seen = False

    # ------------------------------------------------------------------ facts the runner may ask for
    @property
    def dt(self) -> float:
        return self.controller.dt

    @property
    def n(self) -> int:
        return self.controller.n

    @property
    def robot(self) -> RobotModel:
        return self.controller.robot

    @property
    def mode(self) -> str:
        """The active mode (the controller's: a reaction may have overridden the task mode)."""
        return self.controller.mode

    @property
    def task_mode(self) -> str:
        """The mode the task asked for (may differ from :attr:`mode` after a collision reaction)."""
        return self._task_mode

    @property
    def collision_latched(self) -> bool:
        """True after a detected collision triggered a reaction, until :meth:`acknowledge_collision`."""
        return bool(self.controller.reacted)

    # ------------------------------------------------------------------ selection
    def _apply(self, name: str, *, bumpless: bool = True) -> None:
        m = CONTROL_MODES[name]
        self.controller.set_switches(kappa_eps=m.kappa_eps, kappa_ext=m.kappa_ext)
        if not bumpless:  # before the first tick there is nothing to ramp from
            self.controller.reset()

    def select(self, mode: str) -> None:
        """Select the task mode (takes effect at the next :meth:`step`, kappa_eps ramped bumplessly).

        Raises:
            ConfigError: unknown mode; or a collision reaction is latched (the robot stays in its safe
                reaction until :meth:`acknowledge_collision`).
        """
        name = _mode(mode).name
        if self.collision_latched:
            det = self.controller.detector
            when = "" if det is None or det.first_time is None else f" at t = {det.first_time:.3f} s"
            raise ConfigError(
                f"cannot select mode {name!r}: a collision{when} switched the controller to {self.mode!r}; "
                "call acknowledge_collision() first"
            )
        if name != self._task_mode:
            self._task_mode = name
            self._apply(name)
            self._pending_cause = "task"

    def acknowledge_collision(self) -> None:
        """Clear a latched collision and return to the task mode.

        This resets the controller (:meth:`Controller.reset`): the observers restart from the current
        momentum at the next tick (residual 0), so the restored compensation starts from zero.
        """
        self.controller.reset()
        self._collision_seen = False
        self._apply(self._task_mode)
        self._pending_cause = "acknowledged"

    def reset(self) -> None:
        """Back to the initial mode, controller reset, transition log cleared."""
        self.transitions.clear()
        self._task_mode = self._initial
        self._apply(self._initial, bumpless=False)
        self._reported = ""
        self._pending_cause = "task"
        self._collision_seen = False

    # ------------------------------------------------------------------ the tick
    def step(self, measurement: Measurement, reference: Reference) -> Command:
        """Apply the schedule's task mode for this time, run the controller, log a change of mode."""
        if self.schedule is not None and not self.collision_latched:
            wanted = self.schedule.mode_at(measurement.t)
            if wanted != self._task_mode:
                self.select(wanted)
        cmd = self.controller.step(measurement, reference)
        # a fault command may say collision=True (invalid observer): that is logged as a fault
        new_collision = cmd.collision and not cmd.fault and not self._collision_seen
        if new_collision:
            # logged even when the mode does not change (reaction "none", or already compliant)
            det = self.controller.detector
            joints = det.first_joints if det is not None else cmd.collided_joints
            self._log(measurement.t, cmd.mode, "collision", joints)
            self._collision_seen = True
        elif cmd.mode != self._reported:
            if cmd.fault:
                cause = "fault"
            elif self._reported == "fault":
                cause = "recovered"
            else:
                cause = self._pending_cause
            self._log(measurement.t, cmd.mode, cause, ())
        return cmd

    def _log(self, t: float, mode: str, cause: str, joints: tuple[int, ...]) -> None:
        self.transitions.append(ModeTransition(float(t), self._reported, mode, cause, tuple(joints)))
        self._reported = mode

    def describe(self) -> dict[str, object]:
        """JSON-serialisable description (a runner puts it into ``Trace.meta``)."""
        return {
            "type": "ModeSupervisor",
            "initial_mode": self._initial,
            "reaction": self.controller.reaction,
            "schedule": None
            if self.schedule is None
            else [[float(t), m] for t, m in zip(self.schedule.times, self.schedule.modes, strict=True)],
        }

    def log_to(self, trace: object) -> None:
        """Store the transition log in a recorded trace's ``meta["mode_transitions"]`` (any object with ``meta``)."""
        meta = getattr(trace, "meta", None)
        if not isinstance(meta, dict):
            raise ConfigError(f"cannot log mode transitions to {type(trace).__name__}: it has no dict 'meta'")
        meta["mode_transitions"] = self.transitions_as_records()

    def transitions_as_records(self) -> list[dict[str, object]]:
        """The transition log as JSON-serialisable dicts (for ``Trace.meta["mode_transitions"]``)."""
        return [
            {"t": tr.t, "from": tr.from_mode, "to": tr.to_mode, "cause": tr.cause, "joints": list(tr.joints)}
            for tr in self.transitions
        ]
