"""The C++ core (``reflexarm._core``) against the plain numpy/Pinocchio oracle of ``controller_oracle.py``.

Both sides run the same seeded random sequence of measurements and references (with bad ticks). The Python
face, :class:`reflexarm.control.Controller`, is compared with the same oracle in test_controller_oracle.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import reflexarm._core as core

from controller_oracle import (
    DT,
    N_TICKS,
    Oracle,
    core_controller,
    ticks,
    with_springs,
)
from oracle_texts import event_mismatches, expected_text
from reflexarm.control import Controller
from reflexarm.control import contract as _k
from reflexarm.control.collision.react import ReactionSettings
from reflexarm.signals import Measurement, Reference

# Tolerance 1e-9 [Nm, Nms; for the event record also rad, s, J]: both sides call the same Pinocchio functions; they
# differ only in summation order and in the eigen-decomposition of the modal damping (Jacobi rotations vs LAPACK),
# each ~1e-13 relative on quantities of ~1e2 Nm, and the observer's integral carries that over a few hundred ticks
# at most. The exact observer form divides a momentum increment by h = 1e-3 s (the core rebuilds p_{k-1} from its
# integral, the oracle keeps it): ~1e-16 x 10 Nms / 1e-3 s = 1e-12 Nm per tick. A real difference in a reaction is
# a sizeable fraction of a Nm (e.g. brake_time 1 % off: ~1e-1 Nm, test_a_perturbed_brake_time_is_caught).
ATOL = 1e-9

#: Reaction settings short enough that every phase change happens within a run of RUN_TICKS ticks (detection
#: near tick 110 with the 30 1/s detection observer, ~165 with 5 1/s): braking 40 ms then holding, a retract of
#: 0.1 s (the shortest) then holding, the guard at 0.1 s.
SHORT = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1)
RUN_TICKS = 400
#: the phases each reaction goes through in such a run
PHASES = {"gravity": ["gravity"], "brake": ["braking", "holding"], "retract": ["retracting", "holding"],
          "compliant": ["holding"], "none": ["none"]}  # fmt: skip


def compare(k: int, want: dict, ctrl: Any, status: int, o: Oracle | None = None, tau: bool = True) -> None:
    """The core's tick against the oracle's (and its event record against the oracle's when ``o`` is given;
    ``tau=False``: everything but the torque and what follows from it, saturation and torque_limited)."""
    where = f"tick {k}"
    code = status if status < 0 else 0
    assert code == want["code"], f"{where}: code {code} ({ctrl.fault!r}), oracle {want['code']}"
    if tau:
        np.testing.assert_allclose(ctrl.tau, want["tau"], rtol=0, atol=ATOL, err_msg=f"{where}: tau")
        np.testing.assert_array_equal(ctrl.saturated.astype(bool), want["saturated"], err_msg=f"{where}: saturated")
    if code != _k.OBSERVER_INVALID:  # an invalid observer's state is part-way updated: not a number to compare
        np.testing.assert_allclose(ctrl.residual, want["residual"], rtol=0, atol=ATOL, err_msg=f"{where}: residual")
    assert ctrl.collision == want["collision"], where
    assert ctrl.command_mode == want["mode"], where
    np.testing.assert_array_equal(ctrl.collided.astype(bool), want["collided"], err_msg=f"{where}: collided")
    if want["fault"] is not None and code != _k.OBSERVER_INVALID:
        sig, idx, val, lo, hi = ctrl.fault_info
        assert (sig, idx) == tuple(want["fault"][1:3]), where
        np.testing.assert_allclose([val, lo, hi], want["fault"][3:], rtol=1e-12, err_msg=where)
        assert ctrl.fault == expected_text(want["fault"]), where
    if code == 0:
        assert ctrl.fault == "", where
    if o is not None:
        record = ctrl.event
        if not tau:
            record["torque_limited"] = o.event is not None and o.event["torque_limited"]
        bad = event_mismatches(o.event, record, ATOL)
        assert not bad, f"{where}: event " + "; ".join(bad)


def run_both(robot, o: Oracle, ctrl: Any, tau: bool = True, **kw) -> list[int]:
    """Both ticks over the seeded run; the event record is compared on every tick when the oracle detects."""
    codes = []
    for k, args in ticks(robot, **kw):
        if k == 200 and o.reaction == "none" and o.contact_reaction == "none":  # a kappa_eps switch, ramped
            o.set_switches(1 - o.kappa_eps)
            ctrl.set_switches(kappa_eps=1 - ctrl.kappa_eps)
        want = o.step(*args)
        status = ctrl.update(*args)
        compare(k, want, ctrl, status, o if o.threshold is not None else None, tau=tau)
        codes.append(want["code"])
    return codes


def phases_seen(o: Oracle, ctrl: Any, robot, **kw) -> list[str]:
    """run_both, returning the reaction phases the core's event went through."""
    seen: list[str] = []
    for k, args in ticks(robot, **kw):
        compare(k, o.step(*args), ctrl, ctrl.update(*args), o)
        phase = ctrl.event["phase"]
        if ctrl.event["detected"] and (not seen or seen[-1] != phase):
            seen.append(phase)
    return seen


# ---------------------------------------------------------------------- tests
@pytest.mark.parametrize("discretization", ["euler", "exact"])
@pytest.mark.parametrize("kappa_f", [0, 1])
@pytest.mark.parametrize("kappa_eps", [0, 1])
@pytest.mark.parametrize("kappa_ext", [0, 1])
def test_tick_equals_oracle_for_every_switch_combination(atlas, kappa_f, kappa_eps, kappa_ext, discretization):
    o = Oracle(atlas, kappa_f=kappa_f, kappa_eps=kappa_eps, kappa_ext=kappa_ext, threshold=None, reaction="none",
               torque_rate_limit=3000.0 if kappa_f else None, discretization=discretization)  # fmt: skip
    codes = run_both(atlas, o, core_controller(core, atlas, o))
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]


REACTIONS = ["gravity", "brake", "retract", "compliant", "none"]
REACTION_PARAMS = REACTIONS


@pytest.mark.parametrize("reaction", REACTION_PARAMS)
@pytest.mark.parametrize("detection_gain", [None, 30.0])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_detection_and_reaction_equal_oracle(atlas, reaction, detection_gain, discretization):
    """A 40 Nm push from tick 100 (with the run's bad ticks) is detected; each reaction runs through its phases
    (brake -> hold, retract -> hold, compliant hold, gravity, none); tau, residual, mode and the event record
    equal the oracle's on every tick."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=detection_gain,
               switch_time=0.0 if reaction == "compliant" else 0.1, discretization=discretization,
               settings=SHORT)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    seen = phases_seen(o, ctrl, atlas, push=40.0, n_ticks=RUN_TICKS)
    assert o.detected and ctrl.detected, "the 40 Nm push was not detected: the test would prove nothing"
    assert 0.1 < ctrl.first_time < N_TICKS * DT
    assert seen == PHASES[reaction], "the reaction did not go through its phases: the test would prove little"
    event = ctrl.event
    assert event["contact_class"] == "collision" and event["reaction"] == reaction  # kappa_ext = 1: never measured
    assert event["guard_checked"] and event["distal_joint"] >= 1  # the push is on joint 1
    end_mode = {"gravity": "gravity_compensation", "brake": "holding", "retract": "holding", "compliant": "compliant"}
    assert ctrl.mode == o.mode == end_mode.get(reaction, "precise_ee_compliant")
    o.reset()
    ctrl.reset()
    assert ctrl.mode == o.mode and not ctrl.detected and ctrl.kappa_eps == o.kappa_eps == 1
    assert not ctrl.event["detected"]


@pytest.mark.parametrize("reaction", ["retract"])
@pytest.mark.parametrize("measured", [False, True])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_retract_plan_and_phases_equal_oracle(atlas, reaction, measured, discretization):
    """The retract apart from its torque: its goal q_target (the
    direction and length of the motion), the phases, modes, residuals and the rest of the record equal the oracle's.
    The run's measurements do not depend on the commands, so nothing here depends on the torque either."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=0, reaction=reaction, contact_reaction=reaction,
               detection_observer_gain=30.0, discretization=discretization, settings=SHORT)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    run_both(atlas, o, ctrl, tau=False, push=40.0, n_ticks=RUN_TICKS, wrist_force=(12.0, -6.0, 9.0) if measured
             else (0.0, 0.0, 0.0))  # fmt: skip
    assert ctrl.event["contact_class"] == ("contact" if measured else "collision")
    assert ctrl.event["phase"] == "holding" and np.any(ctrl.event["q_target"] != ctrl.event["q_detect"])


#: |cos| of the angle between the retract's joint motion and the admittance reflex M(q)^-1 r: both come from the same
#: M(q) (crba) and r, so they differ by rounding only (~1e-15 relative); the J^T f direction of the core before the
#: admittance reflex is 64 degrees off here (cos 0.43; asserted below to be < 0.9, so that the test can fail).
PARALLEL_COS = 1.0 - 1e-9


def test_the_retract_moves_the_arm_by_its_admittance(atlas):
    """An unmeasured collision: the retract's joint motion q_target - q_detect is the admittance reflex M11^-1 J^T f
    of the joints up to the most distal crossing one at the detecting posture (M11 their block of M(q), J^T f the
    residual on them; the later joints stay put): the velocity an impulse of the contact force gives those joints
    (the heavy proximal joints move less than the light distal ones). The core before it moved along J^T f itself,
    which is not parallel to M11^-1 J^T f here, and then along M(q)^-1 J^T f over all joints, which moved the
    later joints too."""
    # damping_update_period 1: the modal damping's M(q), which the retract uses, is the detecting tick's
    o = Oracle(atlas, kappa_eps=1, kappa_ext=0, reaction="retract", detection_observer_gain=30.0, settings=SHORT,
               damping_update_period=1)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    run_both(atlas, o, ctrl, tau=False, push=40.0, n_ticks=RUN_TICKS)
    ev = ctrl.event
    assert ev["contact_class"] == "collision" and ev["phase"] == "holding"
    k = int(np.flatnonzero(ev["joints"])[-1]) + 1
    r = np.zeros(atlas.n)
    r[:k] = np.asarray(ev["residual"])[:k]
    q = np.asarray(ev["q_detect"])
    M = atlas.compute_mass_matrix(q)
    admittance = np.concatenate([np.linalg.solve(M[:k, :k], r[:k]), np.zeros(atlas.n - k)])
    moved = np.asarray(ev["q_target"]) - q

    def cos(a: np.ndarray, b: np.ndarray) -> float:
        return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))

    assert k < atlas.n and cos(moved, admittance) > PARALLEL_COS
    np.testing.assert_array_equal(moved[k:], 0.0)
    assert cos(r, admittance) < PARALLEL_COS  # J^T f alone (the first direction) would fail the line above
    assert cos(np.linalg.solve(M, r), admittance) < PARALLEL_COS  # so would M^-1 J^T f over all joints


@pytest.mark.parametrize("reaction", REACTION_PARAMS)
@pytest.mark.parametrize("contact_class", ["contact", "collision"])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_classified_reaction_equals_oracle(atlas, reaction, contact_class, discretization):
    """kappa_ext = 0: a detection while the wrist measures 16 N (> contact_level 10 N) is a contact and runs
    contact_reaction, else a collision running reaction; the other one is "none", so a wrong class shows."""
    measured = contact_class == "contact"
    o = Oracle(atlas, kappa_eps=1, kappa_ext=0, reaction="none" if measured else reaction,
               contact_reaction=reaction if measured else "none", detection_observer_gain=30.0,
               discretization=discretization, settings=SHORT)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    force = (12.0, -6.0, 9.0) if measured else (0.0, 0.0, 0.0)  # |f| ~ 16 N with the run's +-2.3 N noise
    seen = phases_seen(o, ctrl, atlas, push=40.0, wrist_force=force, n_ticks=RUN_TICKS)
    event = ctrl.event
    assert (event["contact_class"], event["reaction"]) == (contact_class, reaction)
    assert (event["wrist_force"] > SHORT.contact_level) == measured
    assert seen == PHASES[reaction]


def test_a_measured_force_with_kappa_ext_is_a_collision(atlas):
    """With kappa_ext = 1 the residual excludes what the wrist measures: a detection is never the measured contact."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction="brake", contact_reaction="none",
               detection_observer_gain=30.0, settings=SHORT)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    assert phases_seen(o, ctrl, atlas, push=40.0, wrist_force=(12.0, -6.0, 9.0), n_ticks=RUN_TICKS)
    assert ctrl.event["wrist_force"] > SHORT.contact_level
    assert (ctrl.event["contact_class"], ctrl.event["reaction"]) == ("collision", "brake")


@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_a_perturbed_brake_time_is_caught(atlas, discretization):
    """A deliberately broken core (brake_time 1 % longer in its parameters only) must fail the comparison, and on
    the first braking tick, where the brake's torque M dq / brake_time first counts."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction="brake", detection_observer_gain=30.0, settings=SHORT,
               discretization=discretization)  # fmt: skip
    broken = core_controller(core, atlas, o, brake_time=SHORT.brake_time * 1.01)
    with pytest.raises(AssertionError, match="tau") as caught:
        run_both(atlas, o, broken, push=40.0, n_ticks=RUN_TICKS)
    assert o.event is not None and o.event["phase"] == "braking"
    twin = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction="brake", detection_observer_gain=30.0, settings=SHORT,
                  discretization=discretization)  # fmt: skip
    braking = [k for k, args in ticks(atlas, push=40.0, n_ticks=RUN_TICKS)
               if twin.step(*args)["code"] == 0 and twin.event is not None and twin.event["t_detect"] <= args[0]]
    assert f"tick {braking[0]}: tau" in str(caught.value)  # the first tick of the brake's law: the detecting one


@pytest.mark.parametrize(
    "second_push", [pytest.param(8.0, id="below-threshold"), pytest.param(20.0, id="above-threshold")]
)
def test_recrossings_count_detections_after_the_residual_fell_below_half(atlas, second_push):
    """A 40 Nm push (ticks 100-199), released (the residual falls below half of every threshold), then a second push
    of 8 Nm (under the 11 Nm threshold: no re-contact) or 20 Nm (one re-contact). On this random reference the
    free-motion residual wanders between 0.2 and 0.9 zeta, so hysteresis at half the threshold is what is tested."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction="none", detection_observer_gain=30.0)
    ctrl = core_controller(core, atlas, o)
    run_both(atlas, o, ctrl, push=lambda k: 40.0 if k < 200 else (0.0 if k < 300 else second_push), faults=False,
             n_ticks=RUN_TICKS)  # fmt: skip
    assert o.event is not None and o.event["recrossings"] == (0 if second_push < 11.0 else 1)


def test_invalid_observer_latches_until_reset_like_oracle(atlas):
    o = Oracle(atlas, kappa_eps=1)
    ctrl = core_controller(core, atlas, o)
    codes = []
    for k, args in ticks(atlas, faults=False):
        if k == 120:
            o.obs[0][0][0] = np.nan
            ctrl._set_observer_integral(0, np.nan)
        if k == 200:
            o.reset()
            ctrl.reset()
        want = o.step(*args)
        compare(k, want, ctrl, ctrl.update(*args))
        codes.append(want["code"])
    assert set(codes[120:200]) == {_k.OBSERVER_INVALID} and set(codes[200:]) == {0}
    assert ctrl.fault == ""


def test_joint_springs_enter_g_like_oracle(atlas):
    robot = with_springs(atlas)
    o = Oracle(robot, kappa_f=1, kappa_eps=1, threshold=None, reaction="none")
    run_both(robot, o, core_controller(core, robot, o))


@pytest.mark.parametrize("springs", [False, True])
@pytest.mark.parametrize(("reaction", "discretization"), [("gravity", "euler"), ("brake", "exact")])
def test_core_equals_python_controller(atlas, springs, reaction, discretization):
    """The same run through reflexarm.control.Controller (the face that delegates to the core), event included."""
    atlas = with_springs(atlas) if springs else atlas
    kw = {"kappa_f": 1, "kappa_eps": 1, "kappa_ext": 1, "threshold": 11.0, "reaction": reaction}
    py = Controller(atlas, detection_observer_gain=30.0, torque_rate_limit=3000.0, reaction_settings=SHORT,
                    observer_discretization=discretization, contact_geometry=None, **kw)  # fmt: skip
    o = Oracle(atlas, detection_observer_gain=30.0, torque_rate_limit=3000.0, settings=SHORT,
               discretization=discretization, **kw)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    for k, (t, *rest) in ticks(atlas, push=40.0, n_ticks=RUN_TICKS):
        status = ctrl.update(t, *rest)
        cmd = py.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        where = f"tick {k}"
        np.testing.assert_allclose(ctrl.tau, cmd.tau, rtol=0, atol=ATOL, err_msg=where)
        np.testing.assert_allclose(ctrl.residual, cmd.residual, rtol=0, atol=ATOL, err_msg=where)
        assert (ctrl.fault, ctrl.command_mode, ctrl.collision) == (cmd.fault, cmd.mode, cmd.collision), where
        assert (status if status < 0 else 0) == cmd.fault_code, where
        assert py.mode == ctrl.mode, where
    assert py.detector is not None and ctrl.first_time == py.detector.first_time
    event = py.event
    assert event is not None and event.reaction == reaction and event.guard_checked
    record = {**event.to_dict(), "joints": np.isin(np.arange(atlas.n), event.joints), "detected": True}
    core_record = {k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in ctrl.event.items()}
    core_record["joints"] = np.asarray(core_record["joints"]).astype(bool)
    assert core_record.pop("estimate_from_sensor") is False and core_record["estimate"] is None  # no geometry
    for key, value in core_record.items():
        np.testing.assert_array_equal(np.asarray(record[key], dtype=object), np.asarray(value, dtype=object),
                                      err_msg=key)  # fmt: skip


@pytest.mark.parametrize("value", [0.1, 100.0, 1e-5, 1e-4, 1e16, 1e15, -2.5, 1.5e200, -0.0, 1 / 3, np.inf, -np.inf])
def test_fault_values_are_printed_as_python_repr(value):
    assert core.format_repr(value) == repr(float(value))


def test_inputs_of_another_dtype_or_shape_are_refused(atlas):
    ctrl = core_controller(core, atlas, Oracle(atlas))
    n = atlas.n
    z, g = np.zeros(n), np.array([0.0, 0.0, -9.81])
    with pytest.raises(TypeError):
        ctrl.update(0.001, z.astype(np.float32), z, z, np.zeros(6), g, z, z, z)
    with pytest.raises(TypeError):
        ctrl.update(0.001, z[::2], z, z, np.zeros(6), g, z, z, z)
    assert ctrl.update(0.001, np.zeros(n + 1), z, z, np.zeros(6), g, z, z, z) == _k.BAD_SHAPE
    assert ctrl.fault_info[:3] == (_k.SIG_Q, -1, n + 1)
    assert ctrl.fault == f"measurement q must be a real vector of shape ({n},); got shape ({n + 1},)"


def test_the_period_argument_integrates_like_the_time_stamps(atlas):
    """ros2_control semantics: the observer integrates the periods given since the last accepted tick (rejected
    calls included); with period = 0 the time-stamp difference. Jittery stamps with period 0 and regular stamps
    with the jittery periods give the same commands."""
    o = Oracle(atlas, kappa_eps=1, observer_gain=20.0)
    by_stamps, by_period = core_controller(core, atlas, o), core_controller(core, atlas, o)
    rng = np.random.default_rng(3)
    t = 0.0
    for k, (_, *rest) in ticks(atlas, faults=False):
        h = 7 * DT if k in (50, 120) else rng.uniform(0.3, 1.4) * DT  # some periods outside the band
        t += h
        if k == 100:
            rest[0] = rest[0].copy()
            rest[0][2] = np.nan  # a rejected call: its period still counts towards the next accepted tick
        a = by_stamps.update(t, *rest)
        b = by_period.update_with_period((k + 1) * DT, h, *rest)
        assert a == b, f"tick {k}"
        np.testing.assert_allclose(by_period.tau, by_stamps.tau, rtol=0, atol=ATOL, err_msg=f"tick {k}")
        np.testing.assert_allclose(by_period.residual, by_stamps.residual, rtol=0, atol=ATOL, err_msg=f"tick {k}")
    n_a, sum_a, *_, clipped_a, _, _ = by_stamps.timing
    n_b, sum_b, *_, clipped_b, _, _ = by_period.timing
    assert (n_a, clipped_a) == (n_b, clipped_b) and clipped_a > 10
    assert sum_b == pytest.approx(sum_a, rel=1e-12)  # tolerance: round-off of the summed stamps
    # a negative or non-finite period is a fault on its own signal, and changes nothing
    before = np.array(by_period.observer_residual)
    z = np.zeros(atlas.n)
    g = np.array([0.0, 0.0, -9.81])
    code = by_period.update_with_period(10.0, -1e-3, atlas.home, z, z, np.zeros(6), g, atlas.home, z, z)
    assert code == _k.OUT_OF_BOUNDS and by_period.fault_info[0] == _k.SIG_PERIOD
    assert by_period.fault.startswith("update period = -0.001 s outside the plausible [0, inf] s")
    code = by_period.update_with_period(10.0, np.nan, atlas.home, z, z, np.zeros(6), g, atlas.home, z, z)
    assert code == _k.NON_FINITE and by_period.fault == "non-finite update period = nan"
    np.testing.assert_array_equal(by_period.observer_residual, before)


def test_warm_started_damping_equals_a_fresh_decomposition_after_many_updates(atlas):
    """The damping update starts its eigen-decomposition from the previous eigenvectors; round-off must not
    build up over a long run (without re-orthonormalizing, D drifted by 2e-11 relative in 20000 updates)."""
    ctrl = Controller(atlas, damping_update_period=1, threshold=None, torque_limit=None, stiffness=[100, 200, 300,
                      150, 50, 40, 30])  # fmt: skip
    g = np.array([0.0, 0.0, -9.81])
    z6 = np.zeros(6)
    n_updates = 20000
    for k in range(n_updates):
        t = k * DT
        q = atlas.home + 0.3 * np.sin(2 * np.pi * 0.2 * t + np.arange(atlas.n))
        dq = 0.3 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t + np.arange(atlas.n))
        cmd = ctrl.step(Measurement(t, q, dq, atlas.compute_gravity(q), z6, g), Reference(q, dq, np.zeros(atlas.n)))
        assert cmd.fault == "", cmd.fault
    fresh = core.modal_damping(atlas.compute_mass_matrix(q), ctrl.impedance.stiffness, ctrl.impedance.damping_ratio)
    # tolerance: both are one eigen-decomposition's round-off (~1e-15 relative) away from the exact D
    np.testing.assert_allclose(ctrl.damping, fresh, rtol=0, atol=1e-12 * np.abs(fresh).max())


def test_step_signals_takes_tuples_of_float64_arrays_and_leaves_everything_else_untouched(atlas):
    """The core's step(measurement, reference) path of Controller.step: the same tick as update() on plain
    float64 inputs; None, with the controller unchanged, for inputs it does not read (the Python side converts)."""
    from reflexarm.signals import Command

    o = Oracle(atlas, threshold=11.0)
    ctrl, twin = core_controller(core, atlas, o), core_controller(core, atlas, o)
    ctrl.set_command_type(Command)
    kinds = set()
    for k, (t, *rest) in ticks(atlas, push=40.0):
        m, r = Measurement(t, *rest[:5]), Reference(*rest[5:])
        # not read here: a list, an int t, a float32 vector, a non-tuple, a wrong number of items
        for other in (
            (m._replace(q=list(m.q)), r),
            (m._replace(t=k), r),
            (m, r._replace(ddq_d=r.ddq_d.astype(np.float32))),
            (list(m), r),
            (m[:5], r),
            (m, tuple(r) + (r.q_d,)),
        ):
            before = np.array(ctrl.observer_arrays)
            assert ctrl.step_signals(*other) is None, f"tick {k}"
            np.testing.assert_array_equal(np.array(ctrl.observer_arrays), before, err_msg=f"tick {k}")
        out = ctrl.step_signals(m, r)
        status = twin.update(t, *rest)
        kinds.add(type(out))
        if out.__class__ is int:
            assert out == status, f"tick {k}"
        else:
            assert status == 0 and type(out) is Command, f"tick {k}"
            np.testing.assert_array_equal(out.tau, twin.tau, err_msg=f"tick {k}")  # exact: the same tick
            np.testing.assert_array_equal(out.residual, twin.residual, err_msg=f"tick {k}")
        np.testing.assert_array_equal(ctrl.tau, twin.tau, err_msg=f"tick {k}")
    assert kinds == {int, Command}  # plain ticks and ticks with events or faults were both seen


def _tight(robot):
    """The arm with velocity limits of 0.3 rad/s and ranges of home +- 0.25 rad: the run's random reference (home +-
    0.3 rad at up to 0.66 rad/s) leaves the reactions' safe range (+-0.2 rad) and exceeds the velocity limits."""
    from reflexarm.robots import RobotModel

    m = robot.pin_model.copy()
    m.velocityLimit = np.full(robot.n, 0.3)
    m.lowerPositionLimit = robot.home - 0.25
    m.upperPositionLimit = robot.home + 0.25
    return RobotModel(m, ee_frame=robot.ee_frame, sensor_frame=robot.sensor_frame, friction=robot.friction,
                      home=robot.home)  # fmt: skip


@pytest.mark.parametrize("reaction", ["gravity", "brake", "retract", "compliant"])
def test_reaction_limits_and_shortened_retract_equal_oracle(atlas, reaction):
    """Every reaction (13 included) pulls a joint back into its range and brakes a joint above its velocity limit;
    a retract longer than max_retract_time is shortened (distance and duration together). Equal to the oracle on
    every tick, and the limits' torque was nonzero on many ticks (else the test would prove nothing)."""
    robot = _tight(atlas)
    settings = ReactionSettings(brake_duration=0.04, retract_speed=0.5, rest_time=0.1, max_retract_time=0.05)
    o = Oracle(robot, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=30.0, settings=settings)
    ctrl = core_controller(core, robot, o)
    active = []
    limits = o.limits
    o.limits = lambda q, dq, p: active.append(bool(np.any(out := limits(q, dq, p)))) or out  # type: ignore[method-assign]
    run_both(robot, o, ctrl, push=40.0, n_ticks=RUN_TICKS)
    assert ctrl.event["reaction"] == reaction and sum(active) > 50
    if reaction == "retract":  # the 0.1 s floor of the plan (retract_speed 0.5 m/s) became 0.05 s: half the way
        assert np.isfinite(ctrl.event["retract_planned"]) and ctrl.event["retract_planned"] < settings.retract_distance


def test_reaction_params_defaults_equal_reaction_settings():
    """The core's ReactionParams defaults are ReactionSettings' (the C++ user gets the Python user's reactions, the
    isolation's points per tick included), and to_core carries every field, the integer one as an integer."""
    from dataclasses import fields

    from reflexarm.errors import ConfigError

    settings, params = ReactionSettings(), core.ReactionParams()
    assert {f.name: getattr(params, f.name) for f in fields(settings)} == {
        f.name: getattr(settings, f.name) for f in fields(settings)
    }
    changed = ReactionSettings(isolation_points_per_tick=3, isolation_delay=0.01).to_core(core)
    assert (changed.isolation_points_per_tick, changed.isolation_delay) == (3, 0.01)
    for bad in (0, 2.5, True):
        with pytest.raises(ConfigError, match=f"isolation_points_per_tick must be an integer >= 1; got {bad!r}"):
            ReactionSettings(isolation_points_per_tick=bad)
    assert params.retract_waits_for_estimate is False  # the C++ default is Python's: the retract does not wait
    assert ReactionSettings(retract_waits_for_estimate=True).to_core(core).retract_waits_for_estimate is True
    for bad in (1, 0.0, "yes", None):
        with pytest.raises(ConfigError, match=f"retract_waits_for_estimate must be True or False; got {bad!r}"):
            ReactionSettings(retract_waits_for_estimate=bad)


def test_the_core_refuses_detection_friction_without_a_detection_observer_or_with_a_bad_band(atlas):
    """The C++ user's ControllerParams are checked by the core itself (the Python Controller checks first; the core's
    ConfigError reaches Python as ValueError)."""
    o = Oracle(atlas, threshold=None, reaction="none", detection_observer_gain=100.0, detection_friction_band=0.1)
    core_controller(core, atlas, o)  # accepted
    for changes, message in (
        ({"detection_observer_gain": None}, "detection_kappa_f = 1 needs a detection observer"),
        ({"detection_friction_band": -0.1}, "detection_friction_velocity_band must be a non-negative number"),
        ({"detection_friction_band": float("nan")}, "detection_friction_velocity_band must be a non-negative"),
    ):
        bad = Oracle(atlas, threshold=None, reaction="none", **{**_DET_FRICTION, **changes})
        with pytest.raises(ValueError, match=message):
            core_controller(core, atlas, bad)


_DET_FRICTION = {"detection_observer_gain": 100.0, "detection_friction_band": 0.1}
