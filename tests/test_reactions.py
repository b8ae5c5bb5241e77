"""The math's own promises of the observer discretizations and the reactions, on the compiled Controller.

* exact observer: for a constant external torque on an arm held still the residual is the first-order step
  response tau_ext (1 - e^{-K_o t}) at every tick, at any gain (K_o = 5, 500, 5000 1/s at 1 kHz and 100 Hz); the
  Euler form is tau_ext (1 - (1 - K_o h)^k), refused by the Controller where it is unstable and divergent beyond
  K_o h = 2 (shown with the oracle, which does not refuse);
* brake: on a frictionless arm in free space (``pinsim.RigidBodyPlant``, the controller's own model) the joint
  velocities decay as e^{-t / brake_time}, then the arm is held;
* retract: a measured end-effector contact moves the sensor frame away along J J^T f (a positive component along
  the measured force f) by retract_distance, then the arm is held at the retract's goal;
* compliant: the arm is held at q_detect with c K (c = 0.1), so that at rest c K (q - q_detect) = tau_ext.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import reflexarm._core as core

from controller_oracle import Oracle, core_controller
from pinsim import RigidBodyPlant
from reflexarm.control import Controller
from reflexarm.control.collision.react import ReactionSettings
from reflexarm.errors import ConfigError
from reflexarm.signals import Measurement, Reference

GRAVITY = np.array([0.0, 0.0, -9.81])
#: a constant external torque [Nm] on every joint (within the wrist's 25 Nm limits)
TAU_EXT = np.array([6.0, -12.0, 8.0, 4.0, 2.0, -1.5, 1.0])


def held_still(robot, dt: float, n_ticks: int):
    """Measurements of the arm at rest at home against TAU_EXT: the motors hold tau_m = g(q) - tau_ext, so that
    M ddq = tau_m + tau_ext - g = 0 and the momentum stays 0: over every period the mean external torque the
    observer sees is exactly TAU_EXT."""
    q, z = robot.home, np.zeros(robot.n)
    tau_m = robot.compute_gravity(q) - TAU_EXT
    for k in range(n_ticks):
        yield k, Measurement(k * dt, q, z, tau_m, np.zeros(6), GRAVITY), Reference(q, z, z)


def residuals(ctrl: Controller, robot, dt: float, n_ticks: int) -> np.ndarray:
    return np.array([ctrl.step(m, r).residual for _, m, r in held_still(robot, dt, n_ticks)])


# ---------------------------------------------------------------------------------------------- observer
#: Python Controller refusing the exact form at K_o dt >= 1 (the C++ core accepts it)


def exact_cases():
    for gain in (5.0, 500.0, 5000.0):
        for rate in (1000.0, 100.0):
            for face in ("core", "Controller"):
                yield pytest.param(gain, rate, face, id=f"{gain:g}-{rate:g}Hz-{face}")


@pytest.mark.parametrize(("gain", "rate", "face"), list(exact_cases()))
def test_exact_observer_is_the_first_order_step_response_at_every_tick(atlas, gain, rate, face):
    """The C++ core directly and through the Python Controller."""
    dt = 1.0 / rate
    n_ticks = 400
    if face == "core":
        ctrl = core_controller(core, atlas, Oracle(atlas, observer_gain=gain, threshold=None, reaction="none",
                                                   discretization="exact"), dt=dt)  # fmt: skip
        r = []
        for _, m, ref in held_still(atlas, dt, n_ticks):
            assert ctrl.update(*m, *ref) == 0
            r.append(np.array(ctrl.residual))
        r = np.array(r)
    else:
        r = residuals(Controller(atlas, observer_gain=gain, observer_discretization="exact", dt=dt, threshold=None,
                                 reaction="none"), atlas, dt, n_ticks)  # fmt: skip
    t = np.arange(n_ticks) * dt  # from the first tick, where the observer starts (r = 0)
    want = -np.expm1(-gain * t)[:, None] * TAU_EXT
    # 1e-9 relative: the exact form adds e^{-K h} r + (1 - e^{-K h}) tau_ext with tau_ext exact up to the round-off
    # of g(q) - (g(q) - tau_ext) (~1e-16 x 50 Nm), a few ulps per tick; 1e-9 leaves room for ~1e6 ticks of them
    np.testing.assert_allclose(r, want, rtol=1e-9, atol=0, err_msg=f"K_o = {gain} 1/s at {rate} Hz")
    assert np.all(np.isfinite(r)) and np.abs(r).max() <= np.abs(TAU_EXT).max() * (1 + 1e-12)  # never overshoots


@pytest.mark.parametrize(("gain", "rate"), [(5.0, 1000.0), (5.0, 100.0)])
def test_euler_observer_where_it_is_accepted_is_its_own_recursion(atlas, gain, rate):
    """r_k = (1 - K h) r_{k-1} + K h tau_ext: r_k = tau_ext (1 - (1 - K h)^k), a lag of the exact form's e^{-K t}."""
    dt = 1.0 / rate
    ctrl = Controller(atlas, observer_gain=gain, dt=dt, threshold=None, reaction="none")
    r = residuals(ctrl, atlas, dt, 400)
    want = (1.0 - (1.0 - gain * dt) ** np.arange(400))[:, None] * TAU_EXT
    np.testing.assert_allclose(r, want, rtol=1e-9, atol=1e-12, err_msg=f"K_o = {gain} 1/s at {rate} Hz")


@pytest.mark.parametrize(("gain", "rate"), [(500.0, 1000.0), (5000.0, 1000.0), (500.0, 100.0), (5000.0, 100.0)])
def test_euler_observer_is_refused_where_unstable_and_exact_is_not(atlas, gain, rate):
    dt = 1.0 / rate
    # K_o dt < 1 but K_o dt x period_band[1] >= 1: the band's message; K_o dt >= 1: the observer's own
    with pytest.raises(ConfigError, match=r"observer_gain \* dt (\* period_band\[1\] )?must be < 1"):
        Controller(atlas, observer_gain=gain, dt=dt)
    ctrl = core_controller(core, atlas, Oracle(atlas, observer_gain=gain, discretization="exact"), dt=dt)
    _, m, ref = next(held_still(atlas, dt, 1))
    assert ctrl.update(*m, *ref) == 0  # the core takes the exact form at this gain


@pytest.mark.parametrize("gain", [2500.0, 5000.0])
def test_euler_form_diverges_beyond_k_h_2_where_exact_converges(atlas, gain):
    """What the refusal protects from, on the oracle (1 kHz; it takes any gain): |1 - K h| > 1 makes the Euler
    residual grow as |1 - K h|^k; the exact form at the same gain has converged to tau_ext within a few ticks."""
    runs = {}
    for disc in ("euler", "exact"):
        o = Oracle(atlas, observer_gain=gain, threshold=None, reaction="none", discretization=disc)
        runs[disc] = np.array([o.step(m.t + 1e-3, *m[1:], *r)["residual"] for _, m, r in held_still(atlas, 1e-3, 30)])
    k = np.arange(30)
    want = (1.0 - (1.0 - gain * 1e-3) ** k)[:, None] * TAU_EXT
    np.testing.assert_allclose(runs["euler"], want, rtol=1e-9, atol=1e-9)  # the recursion, as derived
    assert np.abs(runs["euler"][-1]).max() > 1e4 * np.abs(TAU_EXT).max()  # |1 - K h|^29 >= 1.5^29 ~ 1.3e5
    np.testing.assert_allclose(runs["exact"][10:], np.broadcast_to(TAU_EXT, (20, atlas.n)), rtol=1e-9)


# ---------------------------------------------------------------------------------------------- reactions
def run_plant(ctrl: Controller, plant, n_ticks: int, reference, on_detect=None, wrench=None):
    """Close the loop for n_ticks; call on_detect() once on the first command that reports the collision."""
    log, called = [], False
    for _ in range(n_ticks):
        m = plant.measure()
        if wrench is not None:
            m = m._replace(wrench=wrench(m.t, m.q))
        cmd = ctrl.step(m, reference(m.t))
        if cmd.collision and not called and on_detect is not None:
            on_detect()
            called = True
        log.append((m.t, m.q.copy(), m.dq.copy(), cmd.mode))
        plant.step(cmd.tau)
    return log


def test_brake_decays_joint_velocities_as_exp_minus_t_over_brake_time(atlas):
    """A 30 Nm push on joint 1 while the arm moves at 0.25 rad/s (tracking q0 + v t exactly: the plant is the
    model), released at detection: from the brake's first tick dq(t) = dq_b e^{-(t - t_b) / brake_time}."""
    settings = ReactionSettings(brake_time=0.05, brake_duration=0.3)
    v = 0.25 * np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, 1.0])
    push = {"on": True}
    plant = RigidBodyPlant(atlas, tau_ext=lambda t: (30.0 * np.eye(atlas.n)[1]) * (push["on"] and t >= 0.05))
    plant.reset(atlas.home, v)
    ctrl = Controller(atlas, reaction="brake", detection_observer_gain=100.0, reaction_settings=settings)
    z = np.zeros(atlas.n)
    log = run_plant(ctrl, plant, 600, lambda t: Reference(atlas.home + v * t, v, z),
                    on_detect=lambda: push.update(on=False))  # fmt: skip
    event = ctrl.event
    assert event is not None and event.reaction == "brake" and event.phase == "holding"
    assert not event.torque_limited, "the brake saturated: the closed loop is no longer ddq = -dq / brake_time"
    t = np.array([row[0] for row in log])
    dq = np.array([row[2] for row in log])
    kb = int(np.flatnonzero(t > event.t_detect)[0])  # the first command of the brake's law
    braking = (t >= t[kb]) & (t <= event.t_detect + settings.brake_duration)
    assert {row[3] for row, b in zip(log, braking, strict=True) if b} == {"braking"}
    want = dq[kb] * np.exp(-(t[braking] - t[kb]) / settings.brake_time)[:, None]
    # Tolerance 1 % of |dq_b|: the torque is held over each 1 ms tick, so the loop is dq_{k+1} = (1 - h/T) dq_k +
    # O(h^2): (1 - h/T)^k departs from e^{-k h/T} by at most e^{-1} h / (2 T) = 0.37 % of dq_b (at t - t_b = T),
    # plus M(q), C(q, dq) changing within a tick; measured 0.31 %. A brake_time 10 % off gives 3.5 %.
    np.testing.assert_allclose(dq[braking], want, rtol=0, atol=0.01 * np.abs(dq[kb]).max())
    assert np.abs(dq[braking][-1]).max() < 0.01 * np.abs(dq[kb]).max()  # 6 time constants: ~e^-6
    # then held where the brake stopped it: no drift with the exact model
    np.testing.assert_allclose(log[-1][1], event.q_target, rtol=0, atol=1e-4)
    assert not event.still_moving and event.energy_rest < settings.rest_energy_floor


def sensor_pose(robot, q) -> pin.SE3:
    model = robot.pin_model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[robot.sensor_frame_id].copy()


def test_retract_moves_the_sensor_frame_away_along_the_measured_force_and_holds(atlas):
    """A 54 N force on the wrist (measured by its sensor, kappa_ext = 0: the residual sees it, the class is
    "contact") is detected and ends as the arm retracts; the retract moves the sensor frame along J M^-1 J^T f (the
    admittance reflex d = M^-1 J^T f) by retract_planned <= retract_distance, away from the obstacle, and the arm is
    then held at the retract's goal."""
    settings = ReactionSettings()
    f_world = np.array([30.0, -20.0, 40.0])
    model = atlas.pin_model
    data = model.createData()
    contact = {"on": True}

    def wrist_force(t, q):
        """(tau_ext, wrench measured in the sensor frame) of the contact force f_world on the sensor frame."""
        if not (contact["on"] and t >= 0.05):
            return np.zeros(atlas.n), np.zeros(6)
        J = pin.computeFrameJacobian(model, data, q, atlas.sensor_frame_id, pin.LOCAL_WORLD_ALIGNED)
        R = data.oMf[atlas.sensor_frame_id].rotation  # placed by computeFrameJacobian
        return J[:3].T @ f_world, np.concatenate([R.T @ f_world, np.zeros(3)])

    plant = RigidBodyPlant(atlas, posture_torque=lambda t, q: wrist_force(t, q)[0])
    plant.reset(atlas.home)
    # damping_update_period 1: the modal damping's M(q), which the retract uses, is the detecting tick's
    ctrl = Controller(atlas, reaction="none", contact_reaction="retract", detection_observer_gain=100.0,
                      reaction_settings=settings, damping_update_period=1)  # fmt: skip
    z = np.zeros(atlas.n)
    log = run_plant(ctrl, plant, 1500, lambda t: Reference(atlas.home, z, z), wrench=lambda t, q: wrist_force(t, q)[1],
                    on_detect=lambda: contact.update(on=False))  # fmt: skip
    event = ctrl.event
    assert event is not None and (event.contact_class, event.reaction, event.phase) == ("contact", "retract", "holding")
    assert log[-1][3] == "holding" and not event.torque_limited  # (Controller.mode: see test_controller_oracle.py)
    assert "retracting" in {row[3] for row in log}
    # held at the goal (the plant is the model: the hold's steady state is exact; 1e-5 rad after ~1.2 s of hold)
    q_end = log[-1][1]
    np.testing.assert_allclose(q_end, event.q_target, rtol=0, atol=1e-5)
    dq_plan = event.q_target - event.q_detect
    assert np.abs(dq_plan).max() <= settings.max_retract_angle + 1e-12
    # the plan (linear in dq): the frame moves by retract_planned along J M^-1 J^T f (the controller's model is the
    # plant's, so M and J are the plan's; 1e-9: the same Pinocchio terms, summed in another order)
    J = pin.computeFrameJacobian(model, data, event.q_detect, atlas.sensor_frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
    planned = J @ np.linalg.solve(atlas.compute_mass_matrix(event.q_detect), J.T @ f_world)
    moved = J @ dq_plan
    assert abs(np.linalg.norm(moved) - event.retract_planned) < 1e-9
    assert 0.0 < event.retract_planned <= settings.retract_distance + 1e-12
    assert moved @ planned > (1.0 - 1e-9) * np.linalg.norm(moved) * np.linalg.norm(planned)
    # the frame's real motion: away from the obstacle, along f, and at least 2 cm (issue 15)
    dx = sensor_pose(atlas, q_end).translation - sensor_pose(atlas, event.q_detect).translation
    assert dx @ f_world > 0.5 * np.linalg.norm(dx) * np.linalg.norm(f_world)
    assert np.linalg.norm(dx) >= 0.02


def test_compliant_holds_q_detect_at_a_tenth_of_the_stiffness(atlas):
    """A constant 15 Nm on the elbow (a collision: the wrist measures nothing) with kappa_eps = 1: after detection
    the arm is held at q_detect with 0.1 K and no disturbance compensation, so at rest 0.1 K (q - q_detect) equals
    tau_ext on every joint (zero on the joints not pushed) and kappa_eps is 0."""
    tau_ext = 15.0 * np.eye(atlas.n)[3]
    plant = RigidBodyPlant(atlas, tau_ext=lambda t: tau_ext if t >= 0.05 else np.zeros(atlas.n))
    plant.reset(atlas.home)
    ctrl = Controller(atlas, reaction="compliant", kappa_eps=1, stiffness=300.0, detection_observer_gain=100.0)
    z = np.zeros(atlas.n)
    log = run_plant(ctrl, plant, 5000, lambda t: Reference(atlas.home, z, z))
    event = ctrl.event
    assert event is not None and (event.reaction, event.phase, event.contact_class) == ("compliant", "holding",
                                                                                           "collision")  # fmt: skip
    assert ctrl.kappa_eps == 0 and ctrl.mode == "compliant" and event.t_hold == event.t_detect
    q_end = log[-1][1]
    # Tolerance 1e-4 Nm (~1e-5 of the push): the hold's slowest mode (0.1 K with the modal damping of 0.1 K, ratio
    # 0.7) decays at 0.7 sqrt(0.1 lambda_min(M^-1 K)) = 3.0 1/s at home, so ~5 s after detection the transient is
    # ~3e-7 of the 0.5 rad deflection (measured 1e-7 Nm); the deflection itself is 0.5 rad: a stiffness 1 % off
    # misses by 0.15 Nm, q_d = home instead of q_detect by ~1 Nm.
    np.testing.assert_allclose(0.1 * 300.0 * (q_end - event.q_detect), tau_ext, rtol=0, atol=1e-4)
    assert np.abs(q_end - event.q_detect)[3] > 0.4  # the arm did give way


def test_link_retract_moves_only_the_joints_up_to_the_link_and_no_later_point_beyond_retract_distance(atlas):
    """A 60 N push on the forearm (link 3, after the elbow joint elx) that no sensor measures and no geometry locates:
    the retract knows the link (the most distal crossing joint, 3: joints 4-6 get thresholds they cannot reach), not
    the point. Its plan is the admittance reflex of the joints up to the link, d = M11^-1 r (M11 M(q)'s leading 4 x 4
    block, r the residual at detection): the wrist joints stay put, and the farthest-moving point from the link's far
    end on (the later joints' origins, the sensor frame) moves retract_distance, so no point there moves more. Fails
    on the retract before (d = M^-1 r on all joints, scaled to the link's far end alone: the wrist joints moved, and
    here the sensor frame moves more than the elbow's far end)."""
    settings = ReactionSettings()
    model, data = atlas.pin_model, atlas.pin_model.createData()
    jid, arm = 4, np.array([0.05, 0.0, -0.12])  # Pinocchio joint id of elx (joint 3), the point in its frame [m]
    f_world = np.array([-20.0, 45.0, 35.0])
    contact = {"on": True}

    def point_jacobian(q):  # the pushed point's translational Jacobian (world-aligned)
        pin.computeJointJacobians(model, data, q)
        J6 = pin.getJointJacobian(model, data, jid, pin.LOCAL_WORLD_ALIGNED)
        return J6[:3] + np.cross(J6[3:].T, data.oMi[jid].rotation @ arm).T

    def tau_ext(t, q):
        on = contact["on"] and t >= 0.05
        return point_jacobian(q).T @ f_world if on else np.zeros(atlas.n)

    plant = RigidBodyPlant(atlas, posture_torque=tau_ext)
    plant.reset(atlas.home)
    threshold = np.array([11.0, 11.0, 11.0, 2.0, 1e6, 1e6, 1e6])
    # damping_update_period 1: the modal damping's M(q), which the retract uses, is the detecting tick's
    ctrl = Controller(atlas, reaction="retract", threshold=threshold, detection_observer_gain=100.0,
                      contact_geometry=None, reaction_settings=settings, damping_update_period=1)  # fmt: skip
    z = np.zeros(atlas.n)
    run_plant(ctrl, plant, 700, lambda t: Reference(atlas.home, z, z), on_detect=lambda: contact.update(on=False))
    event = ctrl.event
    assert event is not None and (event.contact_class, event.reaction) == ("collision", "retract")
    assert event.phase == "holding" and event.distal_joint == 3
    q0, d = event.q_detect, event.q_target - event.q_detect
    np.testing.assert_array_equal(d[4:], 0.0)  # the wrist joints stay put
    M = atlas.compute_mass_matrix(q0)
    want = np.linalg.solve(M[:4, :4], np.asarray(event.residual)[:4])
    # 1e-9: the same Pinocchio M and residual, solved by Eigen's Cholesky factor there and LAPACK here
    np.testing.assert_allclose(d[:4] / np.linalg.norm(d), want / np.linalg.norm(want), rtol=0, atol=1e-9)
    points = [pin.computeJointJacobian(model, data, q0, j)[:3] for j in range(5, model.njoints)]
    points.append(pin.computeFrameJacobian(model, data, q0, atlas.sensor_frame_id, pin.LOCAL_WORLD_ALIGNED)[:3])
    motion = [float(np.linalg.norm(J @ d)) for J in points]
    assert max(motion) == pytest.approx(event.retract_planned, abs=1e-9)
    assert event.retract_planned <= settings.retract_distance + 1e-12
    assert motion[0] < max(motion)  # the case matters: scaled to the elbow's far end (wrist's origin), some point
    # beyond it would have moved retract_distance x max / motion[0]
    # the pushed point moves away: along J_c M11^-1 J_c^T f, a positive component along f
    assert (point_jacobian(q0) @ d) @ f_world > 0.0
