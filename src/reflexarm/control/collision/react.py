"""React: what the controller does once a collision is detected, and the guard that checks it stops the arm.

The reactions run inside the real-time tick (C++ core, ``cpp/src/reaction.cpp``); this module names them and
holds their settings. A reaction makes the torque of the detecting tick already: the event starts between the
detection and that tick's law, so the arm is not pushed on for one more period (at 1 kHz the tick after detection
carried 0.2-2.8 N / Nm more contact than detection on every arm of ``reflexarm reaction-study``; with the reaction
on the detecting tick, the peak after detection is below the level at detection in the demo and held-stick
scenes). Every reaction's torque is bounded by the controller's torque limit; reference motions
stay below ``velocity_fraction`` x the joints' velocity limits and ``position_margin`` inside their ranges.

* ``"gravity"``: eq. (13), tau = g(q) for good (the paper's reaction). An arm with little joint friction keeps
  the momentum it had and drifts; the guard reports it.
* ``"brake"``: damping injection tau = g(q) + C(q, dq) dq - M(q) dq / brake_time, the closed loop
  ddq = -dq / brake_time, for ``brake_duration``; then the posture reached is held (impedance (2) around it,
  no disturbance compensation).
* ``"retract"``: moves the contact away along the joint motion M11^-1 J^T f of the joints up to the contact's link
  (M11 the block of M(q) of those joints; the later joints stay put), the velocity an impulse of the contact force f
  gives them (the "torque reflex" direction of De Luca, Albu-Schaeffer, Haddadin, Hirzinger, IROS 2006): J^T f is the
  estimated point's J_p^T f, the wrist sensor's J_s^T f for a measured contact, or, when the isolation names the
  link but not the point (or did not run), the residual (a contact force f gives r = J_c^T f) on the joints up to
  the isolated (else the most distal significant, at least the most distal crossing) link. By default
  (``retract_waits_for_estimate`` False) a collision's retract does not wait for the isolation: it is planned on the
  detecting tick from the detection residual, and the isolation runs beside it for the event record. Waiting (True),
  it brakes until the estimate is in (``isolation_delay`` plus the isolation's ticks) and moves the estimated point
  along the estimated force. In ``reflexarm reaction-study --reactions retract --scenarios link,link_held`` (5 arms)
  5 of the 10 retracts from the residual keep below 1 % of their kinetic energy at 0.5 s, 6 of 10 waiting with the
  isolation at 32 units a tick (whose ticks exceed 1.2 x), 2 of 10 waiting at the default 4; the pushed stick,
  which keeps coming, reaches the arm again after either on 4 of the 5 arms. The contact then moves along
  J M11^-1 J^T f, which has a positive
  component along f (away from the obstacle), with the least kinetic energy for that displacement among motions of
  those joints: the light joints move more than the heavy ones (along J^T f itself, the reaction study's
  held-stick retracts peaked at 1.0-1.4 J; with the full M^-1 the later joints moved too, the wrist by up to 0.5 rad
  on Atlas' forearm push). The point (without an estimated point: the farthest-moving of the link's far end and every
  later joint origin and the sensor frame, so that no part of the arm from the contact's link on moves more) moves
  by ``retract_distance`` on a minimum-jerk path (less when the joints' velocity bound and ``max_retract_time``
  shorten it: the light wrist joints move most, so the end-effector retracts of the study plan 2.7-3.5 cm); then
  holds.
* ``"compliant"``: holds the posture at detection at c K (c = ``compliant_stiffness_factor``) with the damping
  sqrt(c) D (the modal damping of c K: the same modes at sqrt(c) times the frequencies), with the disturbance
  compensation off (kappa_eps -> 0, the compliant mode of Fig. 3).
* ``"none"``: detection is reported only.

Every reaction (gravity (13) included) keeps the limits: a joint outside its range minus ``position_margin`` is
pulled back with the controller's stiffness, a joint above its velocity limit is braked in proportion to the
excess with the brake's damping M(q) / ``brake_time``. The paper's experiments never reach either.

The reaction is chosen per class of contact (:mod:`reflexarm.control.collision.classify`): ``reaction`` for a
collision the wrist sensor does not measure, ``contact_reaction`` for an end-effector contact it measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from reflexarm.errors import ConfigError

__all__ = ["REACTIONS", "ReactionSettings", "check_reaction", "check_reactions"]

#: Reactions to a detected collision (see the module's docstring).
REACTIONS = ("gravity", "brake", "retract", "compliant", "none")


def check_reaction(name: object, what: str = "reaction") -> str:
    """``name`` if it is one of :data:`REACTIONS`, else a ConfigError naming the choices."""
    if not isinstance(name, str) or name not in REACTIONS:
        raise ConfigError(f"unknown {what} {name!r}; choose one of: {', '.join(REACTIONS)}")
    return name


def check_reactions(
    reaction: object, contact_reaction: object, settings: object
) -> tuple[str, str, ReactionSettings]:
    """(reaction, contact reaction, settings) of a Controller, checked: ``contact_reaction`` None is ``reaction``,
    ``settings`` None the defaults."""
    chosen = check_reaction(reaction)
    contact = chosen if contact_reaction is None else check_reaction(contact_reaction, "contact_reaction")
    settings = ReactionSettings() if settings is None else settings
    if not isinstance(settings, ReactionSettings):
        raise ConfigError(f"reaction_settings must be a ReactionSettings; got {type(settings).__name__}")
    return chosen, contact, settings


@dataclass(frozen=True)
class ReactionSettings:
    """Settings of the reactions and of the guard that checks they bring the arm to rest.

    Attributes:
        brake_time: brake: time constant of the stop, closed loop ddq = -dq / brake_time [s].
        brake_duration: brake: damping alone this long, then the posture reached is held [s].
        retract_distance: retract: how far the contact moves away [m] (the estimated point, the sensor frame, or,
            with the link only, the farthest-moving point from the link's far end on).
        max_retract_angle: retract: largest motion of any joint [rad].
        retract_speed: retract: mean speed of the contact (as ``retract_distance``) along the retract [m/s].
        max_retract_time: retract: longest retract [s]; a plan that its joints' velocity bound makes longer is
            shortened to this (and its distance with it: ``CollisionEvent.retract_planned``), so that the arm
            rests within ``rest_time``.
        velocity_fraction: reference motions of a reaction stay below this x each joint's velocity limit [-].
        compliant_stiffness_factor: compliant: stiffness of the hold = this x the controller's [-].
        rest_time: the guard checks the kinetic energy this long after detection [s].
        rest_energy_fraction: ... and reports the arm as still moving above this x its energy at detection [-]
        rest_energy_floor: ... and above this energy [J].
        energy_filter_time: the guard's kinetic energy 0.5 dq_f^T p_f uses dq and M(q) dq low-passed with this
            time constant [s] (the paper's velocity noise, 5.5e-2 rad/s, alone gives a few mJ unfiltered on the
            Atlas arm; filtered ~1e-5 J).
        contact_level: a detection while the wrist sensor measures more than this force is a measured
            end-effector contact (with kappa_ext = 0) [N].
        position_margin: postures a reaction holds or moves to stay this far inside the joint limits [rad].
        isolation_delay: a collision is isolated from the detection residual this long after detection [s], when the
            residual has grown from the threshold towards the contact's J^T f (0: at detection); a retract that
            waits for the estimate brakes until then.
        isolation_points_per_tick: the isolation is spread over the ticks: it begins on the tick
            ``isolation_delay`` after detection (that tick's residual and posture) and does at most this many
            units of its fit per following tick (a unit: one candidate point's constrained fit of pass 2, or 16
            points' traces of pass 1; a link without geometry counts one), then spends three more ticks
            finishing (the choice of the link, its estimate, the estimate in), so a link collision is isolated
            ceil(units / this) + 3 ticks after it began (``CollisionEvent.t_estimated``), units = the sum over the
            candidate links of ceil(m / 16) + m (m points; 1 without geometry); a retract waiting for the estimate
            factorises M(q) on the tick it comes in and is planned (and retracts) from the next tick on,
            ceil(units / this) + 4 ticks after the beginning; an integer >= 1. The candidate links are fitted
            from the most proximal on until they settle the choice (``isolate.settled``; the same estimate as
            fitting every one): units are then summed over the links examined. The default, 4, puts every tick
            of the isolation at about issue 15's 1.2 x of the same tick without geometry (inside C++, paired, on
            Atlas, Panda and iiwa14's 2 cm controller geometry, ``python bench/bench_collision_tick.py
            --points-per-tick 4 32 --cpp-rounds 201``: warm 1.20-1.26 x, of which the warm copies' own bias on plain
            ticks is 1.04-1.09 x, as run 1.13-1.24 x; 1.16-1.17 x warm on the machine of 2026-12-06; at 32
            1.5-1.8 x); the estimate is then in 55, 101 and 147 ms after the isolation began (10, 16 and 21 ms at
            32). The ticks that begin the isolation, choose the link and estimate cost 1.1-1.2 x at any budget. No
            reaction waits for it by default (``retract_waits_for_estimate``): the budget sets
            only when the event record has the contact. A retract that waits for it brakes that long: at 4 its
            held-stick runs on the iiwa14s and the UR5-like arm end with 2.3-9.6 times their kinetic energy at
            detection, its link-push runs there with 3.4-44 % (``reflexarm reaction-study --reactions retract
            --reaction-setting retract_waits_for_estimate=true,isolation_points_per_tick=4``); give it 32.
        retract_waits_for_estimate: retract, for a collision the wrist sensor does not measure: False (default)
            planned on the detecting tick from the detection residual on the joints up to the most distal
            significant one (the isolation's first candidate link; at least the most distal crossing one), the
            link's far end and every later joint origin moving ``retract_distance`` at most, while the isolation
            runs for the record; True: brakes until the isolation's estimate is in, then moves the estimated point
            by ``retract_distance`` along the estimated force.
    """

    brake_time: float = 0.05
    brake_duration: float = 0.25
    retract_distance: float = 0.05
    max_retract_angle: float = 0.5
    retract_speed: float = 0.2
    max_retract_time: float = 0.3
    velocity_fraction: float = 0.5
    compliant_stiffness_factor: float = 0.1
    rest_time: float = 0.5
    rest_energy_fraction: float = 0.01
    rest_energy_floor: float = 1e-3
    energy_filter_time: float = 0.02
    contact_level: float = 10.0
    position_margin: float = 0.05
    isolation_delay: float = 0.02
    isolation_points_per_tick: int = 4
    retract_waits_for_estimate: bool = False

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "retract_waits_for_estimate":
                if not isinstance(value, bool):
                    raise ConfigError(f"ReactionSettings.{f.name} must be True or False; got {value!r}")
                continue
            if f.name == "isolation_points_per_tick":
                if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                    raise ConfigError(f"ReactionSettings.{f.name} must be an integer >= 1; got {value!r}")
                continue
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            zero_ok = f.name in ("position_margin", "isolation_delay")
            if not ok or value < 0 or (value == 0 and not zero_ok):
                raise ConfigError(
                    f"ReactionSettings.{f.name} must be a positive number{' (or 0)' if zero_ok else ''}; got {value!r}"
                )

    def to_core(self, core: Any) -> Any:
        """The C++ core's ReactionParams with these values."""
        p = core.ReactionParams()
        for f in fields(self):
            value = getattr(self, f.name)
            exact = f.name in ("isolation_points_per_tick", "retract_waits_for_estimate")
            setattr(p, f.name, value if exact else float(value))
        return p
