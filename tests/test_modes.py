"""The modes of Fig. 3 and the supervisor: closed loops (3), (10), (11) on an exact plant, automatic switch
on a link collision, transition log, bumpless switching."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from pinsim import RigidBodyPlant
from reflexarm.control import CONTROL_MODES, Controller, ModeSchedule, ModeSupervisor
from reflexarm.errors import ConfigError
from reflexarm.robots import CoulombViscousFriction
from reflexarm.signals import Measurement, Reference

DT = 1e-3


def frictionless(robot):
    return robot.with_friction(CoulombViscousFriction.zeros(robot.n))


class WrenchPlant(RigidBodyPlant):
    """The exact ABA plant with a force on the end effector (beyond the wrist sensor) and on a link.

    ``ee_force(t)``: force [N] in the sensor frame, applied at the sensor origin; it is reported by the
    wrist sensor. ``link_torque(t)``: a joint torque [Nm] from a contact on the structure, not measured.
    """

    def __init__(self, robot, ee_force=None, link_torque=None, **kw):
        super().__init__(robot, substeps=2, **kw)
        self.fid = robot.sensor_frame_id
        self.ee_force = ee_force or (lambda t: np.zeros(3))
        self.link_torque = link_torque or (lambda t: np.zeros(robot.n))

    def _f(self, t, q, dq, tau):
        J = pin.computeFrameJacobian(self.model, self.data, q, self.fid, pin.LOCAL)
        total = tau + J[:3].T @ self.ee_force(t) + self.link_torque(t)
        return dq, pin.aba(self.model, self.data, q, dq, total)

    def measure(self):
        m = super().measure()
        return m._replace(wrench=np.concatenate([self.ee_force(self.t), np.zeros(3)]))


def run(plant, ctl, q_d, n_steps):
    ref = Reference.hold(q_d)
    cmds, qs = [], []
    for _ in range(n_steps):
        m = plant.measure()
        cmd = ctl.step(m, ref)
        plant.step(cmd.tau)
        cmds.append(cmd)
        qs.append(m.q)
    return np.array(qs), cmds


def heavier(robot, factor=1.15):
    """A true arm 15 % heavier than the model: the model error delta of (3)."""
    return frictionless(robot).with_inertial_parameters(robot.inertial_parameters() * factor)


K = 150.0
F_EE = np.array([0.0, -30.0, 0.0])  # 30 N along the tool axis, into the end effector (sensor frame)


@pytest.mark.parametrize("mode", list(CONTROL_MODES))
def test_closed_loop_of_each_mode_under_ee_force(atlas, mode):
    # Fig. 3 / eqs. (3), (10), (11): static equilibrium under a constant end-effector force with a model
    # error delta (15 % heavier arm, exact otherwise, no friction, no noise).
    model = frictionless(atlas)
    true = heavier(atlas)
    q_d = atlas.home
    plant = WrenchPlant(true, ee_force=lambda t: F_EE)
    plant.reset(q_d)
    ctrl = Controller(model, stiffness=K, damping_ratio=0.7, observer_gain=10, threshold=None, switch_time=0.0)
    sup = ModeSupervisor(ctrl, mode=mode)
    qs, cmds = run(plant, sup, q_d, 4000)
    q = qs[-1]
    J = true.compute_frame_jacobian(q)
    tau_ee = J[:3].T @ F_EE
    # delta: what the model misses statically, g(q) - g_hat(q)
    delta = -(true.compute_gravity(q) - model.compute_gravity(q))
    lhs = K * (q - q_d)
    # tolerance: 0.3 Nm = 1 % of the largest load torque; the residual's discretisation bias at rest is
    # far below it, the remaining motion after 4 s (10 observer time constants) too.
    atol = 0.3
    if mode == "compliant":  # (3): K(q - q_d) = tau_ext + delta
        np.testing.assert_allclose(lhs, tau_ee + delta, atol=atol)
    elif mode == "precise_stiff":  # (10): K(q - q_d) = 0, the residual carries tau_ext + delta
        np.testing.assert_allclose(lhs, 0.0, atol=atol)
        np.testing.assert_allclose(cmds[-1].residual, tau_ee + delta, atol=atol)
    else:  # (11): K(q - q_d) = tau_ext,EE, the residual carries delta only
        np.testing.assert_allclose(lhs, tau_ee, atol=atol)
        np.testing.assert_allclose(cmds[-1].residual, delta, atol=atol)
    assert cmds[-1].mode == mode
    assert np.abs(tau_ee).max() > 5 and np.abs(delta).max() > 1  # the test has something to show


def test_link_collision_switches_to_compliant_and_is_logged(atlas):
    # precise_ee_compliant is stiff against link contacts; a push on the structure is detected and the
    # supervisor's controller (reaction "compliant") ramps kappa_eps to 0 and holds the posture at detection at
    # 0.1 K: the arm yields as in (3) with that stiffness.
    robot = frictionless(atlas)
    push = np.zeros(robot.n)
    push[1] = 20.0
    t0 = 0.5
    plant = WrenchPlant(robot, link_torque=lambda t: push if t >= t0 else np.zeros(robot.n))
    plant.reset(robot.home)
    ctrl = Controller(robot, stiffness=K, observer_gain=10, threshold=11.0, reaction="compliant", switch_time=0.1)
    sup = ModeSupervisor(ctrl, mode="precise_ee_compliant")
    qs, cmds = run(plant, sup, robot.home, 3000)
    modes = [c.mode for c in cmds]
    assert modes[0] == "precise_ee_compliant" and modes[-1] == "compliant"
    tr = sup.transitions
    assert [(x.from_mode, x.to_mode, x.cause) for x in tr] == [
        ("", "precise_ee_compliant", "task"),
        ("precise_ee_compliant", "compliant", "collision"),
    ]
    assert tr[1].joints == (1,)
    # first-order residual reaching zeta = 11 of 20 Nm with k_o = 10: t = -ln(1 - 11/20)/10 = 0.080 s
    # (tolerance 5 ms: the 1 ms tick plus the arm's own small motion feeding back into the residual)
    assert abs(tr[1].t - t0 - (-np.log(1 - 11 / 20) / 10)) < 0.005
    # after the switch the arm is compliant around the posture at detection: 0.1 K (q - q_detect) = tau_ext (3),
    # to 1 % of the push (exact model)
    event = ctrl.event
    assert event is not None and event.reaction == "compliant" and event.phase == "holding"
    np.testing.assert_allclose(0.1 * K * (qs[-1] - event.q_detect), push, atol=0.2)
    # the task cannot re-select a precise mode while the reaction is latched
    with pytest.raises(ConfigError) as e:
        sup.select("precise_stiff")
    assert "cannot select mode 'precise_stiff': a collision at t = 0.5" in str(e.value)
    assert "call acknowledge_collision() first" in str(e.value)
    records = sup.transitions_as_records()
    assert records[1] == {
        "t": tr[1].t,
        "from": "precise_ee_compliant",
        "to": "compliant",
        "cause": "collision",
        "joints": [1],
    }

    class FakeTrace:
        meta: dict = {}

    trace = FakeTrace()
    sup.log_to(trace)
    assert trace.meta["mode_transitions"] == records
    with pytest.raises(ConfigError, match="cannot log mode transitions to int: it has no dict 'meta'"):
        sup.log_to(3)
    assert sup.describe() == {
        "type": "ModeSupervisor",
        "initial_mode": "precise_ee_compliant",
        "reaction": "compliant",
        "schedule": None,
    }
    sup.acknowledge_collision()
    assert sup.mode == "precise_ee_compliant" and not sup.collision_latched


def test_link_collision_with_gravity_reaction(atlas):
    robot = frictionless(atlas)
    push = np.zeros(robot.n)
    push[0] = 20.0
    plant = WrenchPlant(robot, link_torque=lambda t: push if t >= 0.3 else np.zeros(robot.n))
    plant.reset(robot.home)
    ctrl = Controller(robot, stiffness=K, observer_gain=10, threshold=11.0, reaction="gravity")
    sup = ModeSupervisor(ctrl, mode="precise_stiff")
    qs, cmds = run(plant, sup, robot.home, 600)
    assert sup.transitions[-1].to_mode == "gravity_compensation" and sup.transitions[-1].cause == "collision"
    i = next(k for k, c in enumerate(cmds) if c.mode == "gravity_compensation")
    np.testing.assert_allclose(cmds[i + 1].tau, robot.compute_gravity(qs[i + 1]), atol=1e-9)  # eq. (13)


def test_detection_without_reaction_is_logged_and_mode_kept(atlas):
    robot = frictionless(atlas)
    push = np.zeros(robot.n)
    push[0] = 20.0
    plant = WrenchPlant(robot, link_torque=lambda t: push if t >= 0.3 else np.zeros(robot.n))
    plant.reset(robot.home)
    ctrl = Controller(robot, stiffness=K, observer_gain=10, threshold=11.0, reaction="none")
    sup = ModeSupervisor(ctrl, mode="compliant")
    _, cmds = run(plant, sup, robot.home, 600)
    assert cmds[-1].mode == "compliant"
    assert [(x.from_mode, x.to_mode, x.cause) for x in sup.transitions] == [
        ("", "compliant", "task"),
        ("compliant", "compliant", "collision"),
    ]


def test_schedule_switches_modes_per_task_without_torque_jump(atlas):
    # a task schedule: compliant -> precise_stiff -> precise_ee_compliant, with a model error and an EE
    # force present, so every switch changes what is compensated. Bumpless: kappa_eps is ramped over
    # switch_time, kappa_ext only enters the observer's integrand, so no tick's torque jumps.
    model = frictionless(atlas)
    plant = WrenchPlant(heavier(atlas), ee_force=lambda t: F_EE)
    plant.reset(atlas.home)
    ctrl = Controller(model, stiffness=K, observer_gain=10, threshold=None, switch_time=0.1)
    sup = ModeSupervisor(ctrl, schedule=[(0.0, "compliant"), (1.0, "precise_stiff"), (2.0, "precise_ee_compliant")])
    _, cmds = run(plant, sup, atlas.home, 3000)
    assert [(x.to_mode, x.cause) for x in sup.transitions] == [
        ("compliant", "task"),
        ("precise_stiff", "task"),
        ("precise_ee_compliant", "task"),
    ]
    # at the first tick at or after each start (the test plant's clock accumulates dt in floating point)
    np.testing.assert_allclose([x.t for x in sup.transitions], [0.0, 1.0, 2.0], atol=DT * 1.01)
    taus = np.array([c.tau for c in cmds])
    jumps = np.abs(np.diff(taus, axis=0))
    residual = np.abs(cmds[999].residual).max()
    assert residual > 5.0  # there is something to switch in (the EE load plus delta)
    # largest tick-to-tick torque change around the switches, against the steady sampling noise of the
    # loop (none here: exact plant) plus the ramp: 1/100 of the compensated torque per tick at most,
    # doubled for the arm's own motion during the ramp
    for k in (1000, 2000):
        assert jumps[k - 5 : k + 150].max() < 2 * residual / 100 + 0.05, (k, jumps[k - 5 : k + 150].max())
    # and an instantaneous switch (switch_time = 0) does jump: the ramp is what makes it bumpless
    plant.reset(atlas.home)
    ctrl0 = Controller(model, stiffness=K, observer_gain=10, threshold=None, switch_time=0.0)
    sup0 = ModeSupervisor(ctrl0, schedule=[(0.0, "compliant"), (1.0, "precise_stiff")])
    _, cmds0 = run(plant, sup0, atlas.home, 1100)
    jump0 = np.abs(np.diff([c.tau for c in cmds0], axis=0))[995:1005].max()
    assert jump0 > 0.5 * residual


def test_fault_and_recovery_are_logged(atlas):
    ctrl = Controller(atlas, threshold=None)
    sup = ModeSupervisor(ctrl, mode="precise_stiff")
    good = Measurement(0.0, atlas.home.copy(), np.zeros(7), np.zeros(7), np.zeros(6), np.array([0, 0, -9.81]))
    ref = Reference.hold(atlas.home)
    sup.step(good, ref)
    bad = good._replace(t=0.001, q=np.full(7, np.nan))
    assert sup.step(bad, ref).mode == "fault"
    sup.step(good._replace(t=0.002), ref)
    assert [(x.to_mode, x.cause) for x in sup.transitions] == [
        ("precise_stiff", "task"),
        ("fault", "fault"),
        ("precise_stiff", "recovered"),
    ]
    sup.reset()
    assert sup.transitions == [] and sup.mode == "precise_stiff"


#: What each scene puts on the arm: a model error delta (15 % heavier arm), an end-effector force measured
#: by the wrist sensor, or a link torque nobody measures. Each mode's entry in CONTROL_MODES says which
#: of them the arm yields to (Fig. 3); the test runs the scenes and reads the answer off the arm.
SCENES = ("model_error", "ee_force", "link_torque")
LINK_PUSH = np.array([0.0, 8.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # [Nm] on joint 2


def _static_deflection(atlas, mode, scene):
    """K (q - q_d) at rest [Nm], and the torque the scene applies (what K (q - q_d) equals if the arm yields)."""
    model = frictionless(atlas)
    true = heavier(atlas) if scene == "model_error" else model
    plant = WrenchPlant(
        true,
        ee_force=(lambda t: F_EE) if scene == "ee_force" else None,
        link_torque=(lambda t: LINK_PUSH) if scene == "link_torque" else None,
    )
    plant.reset(atlas.home)
    ctrl = Controller(model, stiffness=K, damping_ratio=0.7, observer_gain=10, threshold=None, switch_time=0.0)
    qs, _ = run(plant, ModeSupervisor(ctrl, mode=mode), atlas.home, 3000)
    q = qs[-1]
    if scene == "model_error":
        applied = model.compute_gravity(q) - true.compute_gravity(q)  # delta of (3)
    elif scene == "ee_force":
        applied = true.compute_frame_jacobian(q)[:3].T @ F_EE
    else:
        applied = LINK_PUSH
    return K * (q - atlas.home), applied


@pytest.mark.parametrize("mode", list(CONTROL_MODES))
def test_each_mode_yields_to_exactly_what_fig3_says(atlas, mode):
    """Per mode and scene, the arm at rest either yields (K (q - q_d) = the applied torque, eq. (3)) or
    holds (K (q - q_d) = 0, the residual compensates it): accurate = holds against the model error,
    ee_compliant = yields to the wrist-measured force, link_compliant = yields to the link torque."""
    flags = CONTROL_MODES[mode]
    expected = {"model_error": not flags.accurate, "ee_force": flags.ee_compliant, "link_torque": flags.link_compliant}
    # tolerance 0.3 Nm: 1 % of the largest load torque, as in the closed-loop test above (3 s = 30
    # observer time constants; the residual's discretisation bias at rest is far below it)
    atol = 0.3
    for scene in SCENES:
        deflection, applied = _static_deflection(atlas, mode, scene)
        # each scene applies well over the tolerance somewhere (the smallest, delta, ~1.8 Nm at home), so
        # "yields" and "holds" cannot both pass
        assert np.abs(applied).max() > 3 * atol, scene
        target = applied if expected[scene] else np.zeros_like(applied)
        np.testing.assert_allclose(deflection, target, atol=atol, err_msg=f"{mode}, {scene}")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(mode="stiff"), "unknown control mode 'stiff'; modes are: compliant, precise_stiff, precise_ee_compliant"),
        (dict(schedule=[]), "a mode schedule needs at least one (t_start, mode) entry"),
        (dict(schedule=[(0.0, "compliant"), (0.0, "precise_stiff")]), "mode schedule times must be strictly"),
        (dict(schedule=[(0.0, "soft")]), "unknown control mode 'soft'"),
        (dict(schedule=[0.0]), "mode schedule entries must be (t_start, mode) pairs; got 0.0"),
    ],
)
def test_bad_modes_raise_named_errors(atlas, kwargs, message):
    with pytest.raises(ConfigError) as e:
        ModeSupervisor(Controller(atlas), **kwargs)
    assert message in str(e.value)


def test_switch_values_other_than_0_1_are_rejected(atlas):
    ctrl = Controller(atlas)
    for name in ("kappa_eps", "kappa_ext", "kappa_f"):
        with pytest.raises(ConfigError, match=f"{name} must be 0 or 1; got 2"):
            ctrl.set_switches(**{name: 2})
    with pytest.raises(ConfigError, match="controller must be a reflexarm Controller; got str"):
        ModeSupervisor("ctrl")  # type: ignore[arg-type]


def test_schedule_mode_at():
    s = ModeSchedule([(0.0, "compliant"), (1.5, "precise_stiff")])
    assert [s.mode_at(t) for t in (-1.0, 0.0, 1.499, 1.5, 9.0)] == [
        "compliant",
        "compliant",
        "compliant",
        "precise_stiff",
        "precise_stiff",
    ]


def test_cutoff_lets_the_excess_over_30Nm_through(atlas):
    # precise_stiff (10) with a 45 Nm link torque on joint 1: the compensation is cut off at 30 Nm, so
    # the arm yields by the excess, K (q_1 - q_d1) = 45 - 30 (exact model, no friction, no noise)
    robot = frictionless(atlas)
    push = np.zeros(robot.n)
    push[0] = 45.0
    plant = WrenchPlant(robot, link_torque=lambda t: push if t >= 0.2 else np.zeros(robot.n))
    plant.reset(robot.home)
    ctrl = Controller(robot, stiffness=K, observer_gain=10, threshold=None, residual_limit=30.0, switch_time=0.0)
    sup = ModeSupervisor(ctrl, mode="precise_stiff")
    qs, cmds = run(plant, sup, robot.home, 2500)
    # tolerance 0.1 Nm: steady state after 23 observer time constants, exact plant
    np.testing.assert_allclose(K * (qs[-1][0] - robot.home[0]), 45.0 - 30.0, atol=0.1)
    np.testing.assert_allclose(cmds[-1].residual[0], 45.0, atol=0.1)  # the observer itself is not clipped


def test_parallel_fast_detection_observer_detects_earlier(atlas):
    # Sec. III-A's proposal: a slow observer (k_o = 10) for compensation, a fast one (k_o = 50) for
    # detection. A 20 Nm push on joint 2 crosses zeta = 11 Nm after -ln(1 - 11/20)/k_o: 80 ms with the
    # slow observer alone, 16 ms with the fast one; the compensation keeps the slow observer's dynamics.
    robot = frictionless(atlas)
    push = np.zeros(robot.n)
    push[1] = 20.0
    t0 = 0.3
    times, residual_at = {}, {}
    for fast in (None, 50.0):
        plant = WrenchPlant(robot, link_torque=lambda t: push if t >= t0 else np.zeros(robot.n))
        plant.reset(robot.home)
        ctrl = Controller(
            robot, stiffness=K, observer_gain=10, detection_observer_gain=fast, threshold=11.0, reaction="none"
        )
        sup = ModeSupervisor(ctrl, mode="precise_ee_compliant")
        run(plant, sup, robot.home, 500)
        times[fast] = sup.transitions[-1].t - t0
        residual_at[fast] = ctrl.observer.residual[1]
    # tolerance 3 ms: the 1 ms tick plus the arm's small motion feeding back into the residual
    assert abs(times[None] - (-np.log(1 - 11 / 20) / 10)) < 0.003
    assert abs(times[50.0] - (-np.log(1 - 11 / 20) / 50)) < 0.003
    # the compensating observer is the slow one in both cases: same residual at the end (0.2 s after)
    np.testing.assert_allclose(residual_at[50.0], residual_at[None], atol=1e-9)
