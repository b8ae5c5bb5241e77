"""reflexarm.control.Controller (the Python face of the C++ core) against the plain numpy/Pinocchio oracle.

Every switch combination (kappa_f, kappa_eps, kappa_ext = DC/EFC, the modal damping updated every tick, every 3rd
(its computation spread over 3 ticks) or every 10th (over 4)), both observer discretizations, a reset while a
damping computation is under way, detection (12) with one or two observers, each reaction (gravity (13), brake,
retract, compliant, none) for a measured contact and an unmeasured collision, the event record
(:attr:`Controller.event`), the faults of the input contract, the invalid-observer latch and the joint springs: the
commands are compared tick by tick over the seeded run of ``controller_oracle.ticks`` (with its NaN, implausible,
repeated-stamp, gravity and late ticks). A deliberately broken oracle (a sign flipped in the exact observer) must
fail the same comparison.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller_oracle import (
    DT,
    FINISHING_TICKS,
    N_TICKS,
    Oracle,
    ticks,
    with_springs,
)
from oracle_texts import event_mismatches, expected_text
from reflexarm.control import Controller
from reflexarm.control import contract as _k
from reflexarm.control.collision.event import CollisionEvent
from reflexarm.control.collision.react import ReactionSettings
from reflexarm.errors import ConfigError
from reflexarm.signals import Command, Measurement, Reference

# Tolerance 1e-9 [Nm, Nms; event record also rad, s, J]: the same Pinocchio functions on both sides; summation order
# and the modal damping's eigen-decomposition (Jacobi rotations in C++, LAPACK in the oracle) differ by ~1e-13
# relative on ~1e2 Nm, which the observer's integral carries over a few hundred ticks at most; the exact observer
# divides a momentum increment by h = 1e-3 s (~1e-12 Nm per tick). A real difference is a sizeable fraction of a Nm.
ATOL = 1e-9

#: Reaction settings short enough that each reaction's phases all happen within RUN_TICKS ticks (as in
#: test_cpp_core.py): braking 40 ms then holding, a retract of 0.1 s then holding, the guard at 0.1 s.
SHORT = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1)
RUN_TICKS = 400
PHASES = {"gravity": ["gravity"], "brake": ["braking", "holding"], "retract": ["retracting", "holding"],
          "compliant": ["holding"], "none": ["none"]}  # fmt: skip
REACTION_PARAMS = list(PHASES)


def controller_like(robot, o: Oracle, **more) -> Controller:
    """A Controller with the oracle's settings (torque_limit: the model's effort limits, as the oracle); ``more``:
    further keywords."""
    return Controller(
        robot,
        stiffness=o.stiffness,
        damping_ratio=o.damping_ratio,
        observer_gain=o.observer_gain,
        detection_observer_gain=o.detection_observer_gain,
        detection_kappa_f=int(o.detection_friction_band is not None),
        detection_friction_velocity_band=o.detection_friction_band,
        threshold=o.threshold,
        reaction=o.reaction,
        contact_reaction=o.contact_reaction,
        reaction_settings=o.settings,
        observer_discretization=o.discretization,
        kappa_f=o.kappa_f,
        kappa_eps=o.kappa_eps,
        kappa_ext=o.kappa_ext,
        residual_limit=o.residual_limit,
        switch_time=o.switch_time,
        dt=DT,
        damping_update_period=o.damping_update_period,
        torque_rate_limit=o.torque_rate_limit,
        contact_geometry=o.geometry,
        isolation_share=o.isolation_share,
        **more,
    )


def compare(k: int, want: dict, cmd: Command, ctrl: Controller, o: Oracle) -> None:
    where = f"tick {k}"
    assert cmd.fault_code == want["code"], f"{where}: {cmd.fault!r}, oracle {want['code']}"
    np.testing.assert_allclose(cmd.tau, want["tau"], rtol=0, atol=ATOL, err_msg=f"{where}: tau")
    if cmd.fault_code != _k.OBSERVER_INVALID:  # a part-way updated invalid state is not a number to compare
        np.testing.assert_allclose(cmd.residual, want["residual"], rtol=0, atol=ATOL, err_msg=f"{where}: residual")
    # the damping matrix the tick used (a live view of the core's) against the oracle's modal damping
    np.testing.assert_allclose(ctrl.damping, o.D, rtol=0, atol=ATOL, err_msg=f"{where}: D")
    assert cmd.collision == want["collision"], where
    assert cmd.mode == want["mode"], where
    assert cmd.collided_joints == tuple(np.flatnonzero(want["collided"]).tolist()), where
    assert cmd.saturated == tuple(np.flatnonzero(want["saturated"]).tolist()), where
    if want["fault"] is not None and cmd.fault_code != _k.OBSERVER_INVALID:
        assert cmd.fault == expected_text(want["fault"]), where
    if cmd.fault_code == 0:
        assert cmd.fault == "" and ctrl.last_fault == "", where
    assert np.all(np.isfinite(cmd.tau)), where
    if o.threshold is not None:
        bad = event_mismatches(o.event, event_record(ctrl.event, o.n), ATOL)
        assert not bad, f"{where}: event " + "; ".join(bad)


def event_record(event: CollisionEvent | None, n: int) -> dict:
    """The Python CollisionEvent as the oracle's record (joints as a mask; before a detection: not detected)."""
    if event is None:
        return {"detected": False}
    record = {f: getattr(event, f) for f in event.__dataclass_fields__}
    record["joints"] = np.isin(np.arange(n), event.joints)
    return {"detected": True, **record}


def run_both(robot, o: Oracle, ctrl: Controller, **kw) -> list[int]:
    codes = []
    for k, (t, *rest) in ticks(robot, **kw):
        if k == 200 and o.reaction == "none" and o.contact_reaction == "none":  # a kappa_eps switch, ramped
            o.set_switches(1 - o.kappa_eps)
            ctrl.set_switches(kappa_eps=1 - ctrl.kappa_eps)
        want = o.step(t, *rest)
        cmd = ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        compare(k, want, cmd, ctrl, o)
        assert ctrl.mode == o.mode, f"tick {k}"
        codes.append(want["code"])
    return codes


def phases_seen(robot, o: Oracle, ctrl: Controller, **kw) -> list[str]:
    """run_both, returning the reaction phases Controller.event went through."""
    seen: list[str] = []
    for k, (t, *rest) in ticks(robot, **kw):
        want = o.step(t, *rest)
        compare(k, want, ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:])), ctrl, o)
        assert ctrl.mode == o.mode, f"tick {k}"
        event = ctrl.event
        if event is not None and (not seen or seen[-1] != event.phase):
            seen.append(event.phase)
    return seen


@pytest.mark.parametrize("damping_update_period", [1, 3, 10])
@pytest.mark.parametrize("kappa_f", [0, 1])
@pytest.mark.parametrize("kappa_eps", [0, 1])
@pytest.mark.parametrize("kappa_ext", [0, 1])
def test_controller_equals_oracle_for_every_switch_combination(atlas, kappa_f, kappa_eps, kappa_ext,
                                                                damping_update_period):  # fmt: skip
    o = Oracle(atlas, kappa_f=kappa_f, kappa_eps=kappa_eps, kappa_ext=kappa_ext, threshold=None, reaction="none",
               damping_update_period=damping_update_period, damping_ratio=0.5 + 0.2 * kappa_f,
               torque_rate_limit=3000.0 if kappa_f else None)  # fmt: skip
    codes = run_both(atlas, o, controller_like(atlas, o))
    # the run must have exercised accepted ticks and each kind of fault, or the comparison proves little
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]


@pytest.mark.parametrize("kappa_f", [0, 1])
@pytest.mark.parametrize("kappa_eps", [0, 1])
@pytest.mark.parametrize("kappa_ext", [0, 1])
def test_exact_observer_of_controller_equals_oracle(atlas, kappa_f, kappa_eps, kappa_ext):
    """observer_discretization="exact" (a detection observer of 800 1/s beside the 5 1/s one: K dt = 0.8, refused
    by the Euler form at the band's 2 dt, stable here) over the run with its clipped late tick."""
    o = Oracle(atlas, kappa_f=kappa_f, kappa_eps=kappa_eps, kappa_ext=kappa_ext, threshold=None, reaction="none",
               detection_observer_gain=800.0, discretization="exact")  # fmt: skip
    codes = run_both(atlas, o, controller_like(atlas, o))
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]


@pytest.mark.parametrize("kappa_f", [0, 1])
@pytest.mark.parametrize("kappa_ext", [0, 1])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_detection_observer_s_own_friction_equals_oracle(atlas, kappa_f, kappa_ext, discretization):
    """detection_kappa_f = 1 with a band of 0.1 rad/s (5x the model's): the detection observer subtracts its own
    friction model, the compensating one follows kappa_f; the oracle with the model's band instead (the band not
    passed on) must differ, or the comparison would not see the band."""
    o = Oracle(atlas, kappa_f=kappa_f, kappa_ext=kappa_ext, threshold=None, reaction="none",
               detection_observer_gain=200.0, discretization=discretization, detection_friction_band=0.1)  # fmt: skip
    assert atlas.friction.velocity_band != 0.1 and np.any(atlas.friction.coulomb > 0)
    codes = run_both(atlas, o, controller_like(atlas, o))
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]
    broken = Oracle(atlas, kappa_f=kappa_f, kappa_ext=kappa_ext, threshold=None, reaction="none",
                    detection_observer_gain=200.0, discretization=discretization,
                    detection_friction_band=atlas.friction.velocity_band)  # fmt: skip
    with pytest.raises(AssertionError):
        run_both(atlas, broken, controller_like(atlas, o))


def test_detection_kappa_f_is_refused_without_a_detection_observer_or_with_a_bad_band(atlas):
    with pytest.raises(ConfigError, match="detection_kappa_f = 1 needs a detection observer"):
        Controller(atlas, detection_kappa_f=1)
    with pytest.raises(ConfigError, match="detection_kappa_f"):
        Controller(atlas, detection_observer_gain=100.0, detection_kappa_f=2)
    with pytest.raises(ConfigError, match="give detection_kappa_f=1 with it"):
        Controller(atlas, detection_observer_gain=100.0, detection_friction_velocity_band=0.1)
    for band in (0.0, -0.1, float("nan")):
        with pytest.raises(ConfigError, match="detection_friction_velocity_band"):
            Controller(atlas, detection_observer_gain=100.0, detection_kappa_f=1, detection_friction_velocity_band=band)


@pytest.mark.parametrize("reaction", REACTION_PARAMS)
@pytest.mark.parametrize("detection_gain", [None, 30.0])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_detection_and_reaction_of_controller_equal_oracle(atlas, reaction, detection_gain, discretization):
    """A 40 Nm push from tick 100 is detected; each reaction runs through its phases; Command and Controller.event
    equal the oracle's on every tick."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=detection_gain,
               switch_time=0.0 if reaction == "compliant" else 0.1, settings=SHORT,
               discretization=discretization)  # fmt: skip
    ctrl = controller_like(atlas, o)
    seen = phases_seen(atlas, o, ctrl, push=40.0, n_ticks=RUN_TICKS)
    assert o.detected and ctrl.detector is not None and ctrl.detector.detected, "the 40 Nm push went undetected"
    assert ctrl.detector.first_time is not None and 0.1 < ctrl.detector.first_time < N_TICKS * DT
    assert seen == PHASES[reaction], "the reaction did not go through its phases: the test would prove little"
    end_mode = {"gravity": "gravity_compensation", "brake": "holding", "retract": "holding", "compliant": "compliant"}
    assert ctrl.mode == o.mode == end_mode.get(reaction, "precise_ee_compliant")
    assert ctrl.reacted == (reaction != "none")
    o.reset()
    ctrl.reset()
    assert ctrl.mode == o.mode and not ctrl.reacted and ctrl.kappa_eps == o.kappa_eps == 1
    assert not ctrl.detector.detected and ctrl.detector.first_time is None and ctrl.event is None


@pytest.mark.parametrize("reaction", REACTION_PARAMS)
@pytest.mark.parametrize("contact_class", ["contact", "collision"])
def test_classified_reaction_of_controller_equals_oracle(atlas, reaction, contact_class):
    """kappa_ext = 0: a detection while the wrist measures ~16 N (> contact_level) runs contact_reaction, else
    reaction (the other one "none", so a wrong class shows); exact observer."""
    measured = contact_class == "contact"
    o = Oracle(atlas, kappa_eps=1, kappa_ext=0, reaction="none" if measured else reaction,
               contact_reaction=reaction if measured else "none", detection_observer_gain=30.0, settings=SHORT,
               discretization="exact")  # fmt: skip
    ctrl = controller_like(atlas, o)
    force = (12.0, -6.0, 9.0) if measured else (0.0, 0.0, 0.0)
    assert phases_seen(atlas, o, ctrl, push=40.0, wrist_force=force, n_ticks=RUN_TICKS) == PHASES[reaction]
    event = ctrl.event
    assert event is not None and (event.contact_class, event.reaction) == (contact_class, reaction)


class FlippedExactOracle(Oracle):
    """A deliberately broken oracle: the exact observer's momentum increment with the wrong sign."""

    @staticmethod
    def exact_step(r, k_o, h, dp, beta):
        return Oracle.exact_step(r, k_o, h, -dp, beta)


class PushingBrakeOracle(Oracle):
    """A deliberately broken oracle: the brake's damping injection with the wrong sign (+M dq / brake_time)."""

    def reaction_torque(self, t, q, dq, g, C, p, tau_f):
        tau = super().reaction_torque(t, q, dq, g, C, p, tau_f)
        if self.event is not None and self.event["phase"] == "braking":
            return tau + 2.0 * p / self.settings.brake_time
        return tau


@pytest.mark.parametrize(
    ("broken", "message"),
    [(FlippedExactOracle, "tick 1: tau"), (PushingBrakeOracle, r"tick 1\d\d: tau")],
    ids=["exact-observer-sign", "brake-sign"],
)
def test_a_broken_oracle_fails_the_comparison(atlas, broken, message):
    """The comparison has teeth: a sign flipped in the exact observer (caught on the first observer tick: with
    kappa_eps = 1 the residual enters tau) or in the brake (caught on its first tick, after the detection ~ tick 110)
    fails it, where the correct oracle passes."""
    kw = {"kappa_eps": 1, "kappa_ext": 1, "reaction": "brake", "detection_observer_gain": 30.0, "settings": SHORT,
          "discretization": "exact"}  # fmt: skip
    run_both(atlas, Oracle(atlas, **kw), controller_like(atlas, Oracle(atlas, **kw)), push=40.0, n_ticks=RUN_TICKS)
    o = broken(atlas, **kw)
    with pytest.raises(AssertionError, match=message):
        run_both(atlas, o, controller_like(atlas, o), push=40.0, n_ticks=RUN_TICKS)


def test_invalid_observer_of_controller_latches_until_reset_like_oracle(atlas):
    o = Oracle(atlas, kappa_eps=1)
    ctrl = controller_like(atlas, o)
    codes = []
    for k, (t, *rest) in ticks(atlas, faults=False):
        if k == 120:  # a numerical blow-up, injected into both states (ctrl.observer views the core's state)
            o.obs[0][0][0] = np.nan
            ctrl.observer._integral[0] = np.nan
        if k == 200:
            o.reset()
            ctrl.reset()
        want = o.step(t, *rest)
        cmd = ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        compare(k, want, cmd, ctrl, o)
        codes.append(want["code"])
    assert set(codes[120:200]) == {_k.OBSERVER_INVALID} and set(codes[200:]) == {0}
    assert not ctrl.observer_invalid and ctrl.last_fault == ""


def test_joint_springs_enter_g_of_controller_like_oracle(atlas):
    robot = with_springs(atlas)
    o = Oracle(robot, kappa_f=1, kappa_eps=1, threshold=None, reaction="none")
    run_both(robot, o, controller_like(robot, o))


def test_reset_while_the_damping_is_being_computed_starts_over_like_oracle(atlas):
    """A reset in the middle of a spread damping computation: the next tick computes D whole, from its own M(q)."""
    o = Oracle(atlas, kappa_f=1, kappa_eps=1, threshold=None, reaction="none")
    ctrl = controller_like(atlas, o)
    in_flight = []
    for k, (t, *rest) in ticks(atlas, faults=False):
        if k in (152, 283):
            in_flight.append(o.pending is not None)
            o.reset()
            ctrl.reset()
        want = o.step(t, *rest)
        cmd = ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        compare(k, want, cmd, ctrl, o)
    assert in_flight == [True, True], "the resets did not fall inside a damping computation: the test proves little"


def test_mode_follows_a_phase_change_without_a_threshold_crossing(atlas):
    """A 15 ms push (detected), released: the residual is back under the threshold when the brake's 0.1 s end and
    the arm is held; Controller.mode and every Command.mode must say so."""
    settings = ReactionSettings(brake_duration=0.1)
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction="brake", detection_observer_gain=30.0, settings=settings)
    ctrl = controller_like(atlas, o)
    modes = []
    for k, (t, *rest) in ticks(atlas, push=lambda k: 40.0 if k < 115 else 0.0, faults=False, n_ticks=RUN_TICKS):
        want = o.step(t, *rest)
        cmd = ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        modes.append((k, cmd.mode, ctrl.mode, want["mode"]))
    assert o.event is not None and o.event["phase"] == "holding"
    wrong = [m for m in modes if not m[1] == m[2] == m[3]]
    assert not wrong, f"{len(wrong)} ticks with a wrong mode (tick, Command.mode, Controller.mode, oracle): {wrong[:3]}"


@pytest.mark.parametrize(("reaction", "waits"), [("retract", True), ("retract", False), ("brake", False)])
def test_tick_isolation_and_retract_equal_the_plain_isolator(panda_contact, reaction, waits):
    """A static arm at the contact's posture; from tick 100 the contact's J_c^T f appears (tau_m = g - J_c^T f). The
    Controller isolates it in the ticks (C++ ContactIsolator, begun isolation_delay after detection, spread over
    the ticks, in on the tick the oracle computes from the point counts of the links examined: fewer than the
    candidates here, so the early stop counts): link, point and force equal the plain Python ContactIsolator on
    the same residual and geometry (the oracle's), every tick equals the oracle (a retract that waits: the estimated
    point moved along the estimated force; one that does not: retracting from the detecting tick on, planned from the
    detection residual, while the isolation runs as with the brake), and the estimate is the truth's: same link,
    point within the candidate spacing, force along the true one (a step through the exact first-order observer
    scales J_c^T f without turning it)."""
    from reflexarm.control.collision import ContactIsolator, Determined

    robot, geometry, c = panda_contact
    settings = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1,
                                retract_waits_for_estimate=waits)  # fmt: skip
    o = Oracle(robot, threshold=11.0, reaction=reaction, detection_observer_gain=200.0, discretization="exact",
               settings=settings, geometry=geometry)  # fmt: skip
    ctrl = controller_like(robot, o)
    g = robot.compute_gravity(c.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    residuals, modes = {}, []
    for k in range(400):
        tau_m = g - (c.torque if k >= 100 else 0.0)
        args = ((k + 1) * DT, c.q, zeros, tau_m, np.zeros(6), gravity, c.q, zeros, zeros)
        want = o.step(*args)
        cmd = ctrl.step(Measurement(*args[:6]), Reference(*args[6:]))
        compare(k, want, cmd, ctrl, o)
        residuals[args[0]] = ctrl.detection_residual.copy()
        modes.append(cmd.mode)
    event = ctrl.event
    assert event is not None and event.estimate is not None and event.contact_class == "collision"
    # isolated from the detection residual isolation_delay (20 ms) after detection, spread over the ticks: the
    # estimate in (the retract planned on the tick after) on the tick the oracle's rule gives from the point counts
    assert event.t_estimate == pytest.approx(event.t_detect + settings.isolation_delay, abs=0.5 * DT)
    spread = o.isolation_ticks(c.q, residuals[event.t_estimate])
    assert spread > 1  # the default budget spreads the Panda's distal links over several ticks
    counts = geometry.point_counts()[o.isolator.candidate_links(residuals[event.t_estimate])[0] :]
    every = -(-int(np.sum(np.where(counts > 0, -(-counts // 16) + counts, 1))) // settings.isolation_points_per_tick)
    assert spread < every + 3  # fewer ticks than fitting every candidate link would take (the early stop)
    assert event.t_estimated == pytest.approx(event.t_estimate + spread * DT, abs=0.5 * DT)
    assert (event.t_estimate, event.t_estimated) == (o.t_estimate, o.t_estimated)
    k_in = int(round(event.t_estimated / DT)) - 1
    k_det = int(round(event.t_detect / DT)) - 1
    if reaction == "retract" and waits:  # M(q) factorised on the tick the estimate is in, the plan on the next
        assert modes[k_det : k_det + 2] == ["braking", "braking"]
        assert modes[k_in - 1 : k_in + 2] == ["braking", "braking", "retracting"]
    elif reaction == "retract":  # from the detecting tick on, the isolation running beside it
        assert modes[k_det : k_det + 2] == ["retracting", "retracting"] and modes[k_det - 1] != "retracting"
    plain = ContactIsolator(robot, significance=0.25 * 11.0, geometry=geometry).isolate(
        c.q, residuals[event.t_estimate]
    )
    est = event.estimate
    assert (est.link, est.determined) == (plain.link, plain.determined) == (c.link, Determined.POINT_AND_FORCE)
    np.testing.assert_allclose(est.point, plain.point, atol=1e-12)  # the same candidate point
    np.testing.assert_allclose(est.force, plain.force, rtol=1e-9, atol=1e-8)  # 3x3 solves: see test_isolation_core
    assert np.linalg.norm(est.point - c.point) < geometry.spacing  # [m] the nearest candidate to the true point
    cos = est.force @ c.force / (np.linalg.norm(est.force) * np.linalg.norm(c.force))
    assert cos > np.cos(np.radians(10.0))
    if reaction == "retract":  # the true point moves along the true force, by about retract_distance
        from reflexarm.control.collision.identify import compute_link_kinematics

        kin = compute_link_kinematics(robot, c.q)
        J = kin.jacobians[c.link]
        Jp = J[:3] + np.cross(J[3:].T, c.point - kin.origins[c.link]).T
        moved = Jp @ (event.q_target - event.q_detect)
        assert moved @ c.force > 0.8 * np.linalg.norm(moved) * np.linalg.norm(c.force)
        if waits:  # the estimated point is the one scaled to retract_distance
            assert abs(np.linalg.norm(moved) - event.retract_planned) < 0.2 * event.retract_planned
        else:  # the link's far end and the later joints' origins are scaled (not the point): >= 2 cm (issue 15)
            assert np.linalg.norm(moved) > 0.02 and event.retract_planned <= settings.retract_distance + 1e-12


@pytest.mark.parametrize(("period", "mass"), [(10, "damping"), (41, "own")])
def test_retract_after_isolation_factorises_the_dampings_m_while_it_is_recent(panda_contact, period, mass):
    """The contact of the test above on an arm that keeps moving (0.5 rad/s along one direction, q changes by 5e-4 rad
    a tick; tau_m = g + C dq - J_c^T f from tick 100): the retract that waited for the estimate factorises its M(q) on
    the tick the estimate comes in, the modal damping's (its last crba, every `period` accepted ticks) when that is at
    most 10 ticks old, else that tick's own, and is planned on the next tick from that tick's q and Jacobians: at
    period 10 always the damping's M, at 41 here its own (the estimate comes in 28 ticks after the last crba). Every
    tick is compared with the oracle (q_target to 1e-9; the other M moves it by 4e-5 rad at period 10, 1.1e-3 rad at
    41)."""
    robot, geometry, c = panda_contact
    settings = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1, retract_waits_for_estimate=True)
    o = Oracle(robot, threshold=11.0, reaction="retract", detection_observer_gain=200.0, discretization="exact",
               settings=settings, geometry=geometry, damping_update_period=period)  # fmt: skip
    ctrl = controller_like(robot, o)
    u = np.linspace(1.0, -1.0, robot.n) / np.linalg.norm(np.linspace(1.0, -1.0, robot.n))
    dq, zeros, gravity = 0.5 * u, np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    data = robot.pin_model.createData()
    for k in range(400):
        q = c.q + dq * (k * DT)
        tau_m = robot.compute_gravity(q) + pin.computeCoriolisMatrix(robot.pin_model, data, q, dq) @ dq
        tau_m = tau_m - (c.torque if k >= 100 else 0.0)
        args = ((k + 1) * DT, q, dq, tau_m, np.zeros(6), gravity, q, dq, zeros)
        want = o.step(*args)
        cmd = ctrl.step(Measurement(*args[:6]), Reference(*args[6:]))
        compare(k, want, cmd, ctrl, o)
    event = ctrl.event
    assert event is not None and event.estimate is not None and event.phase in ("retracting", "holding")
    assert np.isfinite(event.retract_planned) and event.retract_planned > 0.0
    assert o.retract_mass == mass


@pytest.mark.parametrize("points_per_tick", [1, 24, 100000])
def test_reset_in_the_middle_of_an_isolation_leaves_nothing_behind(panda_contact, points_per_tick):
    """The contact of the test above, reset() while the isolation is under way (begun, not in), then the same run
    again: every tick equals a fresh oracle's (the old isolation neither finishes nor shifts the new one), and the
    budget decides when the estimate comes in (100000: the fit on the tick after it began)."""
    robot, geometry, c = panda_contact
    settings = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1,
                                isolation_points_per_tick=points_per_tick)  # fmt: skip
    kw = dict(threshold=11.0, reaction="retract", detection_observer_gain=200.0, discretization="exact",
              settings=settings, geometry=geometry)  # fmt: skip
    ctrl = controller_like(robot, Oracle(robot, **kw))
    g = robot.compute_gravity(c.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])

    def args(k: int, t0: float) -> tuple:
        tau_m = g - (c.torque if k >= 100 else 0.0)
        return (t0 + (k + 1) * DT, c.q, zeros, tau_m, np.zeros(6), gravity, c.q, zeros, zeros)

    for k in range(400):  # up to the tick the isolation began (and no further)
        a = args(k, 0.0)
        ctrl.step(Measurement(*a[:6]), Reference(*a[6:]))
        ev = ctrl.event
        if ev is not None and ev.t_estimate == a[0]:
            break
    assert ev is not None and ev.estimate is None and not np.isnan(ev.t_estimate), "no isolation under way"
    ctrl.reset()
    assert ctrl.event is None
    o = Oracle(robot, **kw)
    for k in range(400):
        a = args(k, 1.0)
        want = o.step(*a)
        cmd = ctrl.step(Measurement(*a[:6]), Reference(*a[6:]))
        compare(k, want, cmd, ctrl, o)
    event = ctrl.event
    assert event is not None and event.t_estimate == o.t_estimate
    if points_per_tick == 1:  # thousands of units: still under way after 400 ticks, like the oracle's
        assert event.estimate is None and np.isnan(event.t_estimated) and np.isnan(o.t_estimated)
        return
    assert event.estimate is not None and event.estimate.link == c.link and event.t_estimated == o.t_estimated
    if points_per_tick == 100000:  # the fit on the tick after it began, then the finishing ticks
        assert event.t_estimated == pytest.approx(event.t_estimate + (1 + FINISHING_TICKS) * DT, abs=0.5 * DT)
