"""The input contract of Controller.step, one test per finding 1-7 of issue 8 (each failed on the main of
the time), plus the documented choices around it (recovery, saturation reporting, timing statistics)."""

from __future__ import annotations

import numpy as np
import pytest

from controller_checks import detected_as_by_a_fresh_controller, settled_plant
from reflexarm.control import Controller, InputBounds, JointImpedanceController
from reflexarm.control import contract as _k
from reflexarm.errors import ConfigError, SignalError
from reflexarm.robots import CoulombViscousFriction
from reflexarm.signals import Measurement, Reference

DT = 1e-3


def good(robot, k=0, **over):
    """A plausible measurement at tick k: the arm at rest at home, holding against gravity."""
    base = dict(
        t=k * DT,
        q=robot.home.copy(),
        dq=np.zeros(robot.n),
        tau_m=robot.compute_gravity(robot.home),
        wrench=np.zeros(6),
        gravity=np.array([0.0, 0.0, -9.81]),
    )
    base.update(over)
    return Measurement(**base)


def frictionless(robot):
    return robot.with_friction(CoulombViscousFriction.zeros(robot.n))


# ---------------------------------------------------------------- finding 1
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_q_on_a_damping_update_tick_gives_the_safe_command(atlas, bad):
    # the 10th tick recomputes D from M(q) (Cholesky): it used to raise numpy.linalg.LinAlgError
    ctrl = Controller(atlas, damping_update_period=10)
    ref = Reference.hold(atlas.home)
    for k in range(10):
        assert ctrl.step(good(atlas, k), ref).fault == ""
    D = ctrl.impedance.damping.copy()
    q = atlas.home.copy()
    q[2] = bad
    cmd = ctrl.step(good(atlas, 10, q=q), ref)
    assert cmd.mode == "fault" and "measurement q[2]" in cmd.fault
    np.testing.assert_array_equal(ctrl.impedance.damping, D)  # the damping update did not happen
    assert ctrl.step(good(atlas, 11), ref).fault == ""
    # the impedance law on its own refuses the update without raising and keeps the old D
    imp = JointImpedanceController(atlas, stiffness=300)
    D0 = imp.update_damping(atlas.home).copy()
    assert imp.maybe_update_damping(np.full(atlas.n, np.nan)) is False
    np.testing.assert_array_equal(imp.damping, D0)


# ---------------------------------------------------------------- finding 2
ABSURD = [("dq", 1e200), ("tau_m", 1e150), ("wrench", 1e300), ("gravity", 1e300), ("q", 1e300)]


@pytest.mark.parametrize("kappa_eps", [0, 1])
@pytest.mark.parametrize("field, value", ABSURD)
def test_an_absurd_sample_neither_poisons_the_observer_nor_silences_detection(atlas, field, value, kappa_eps):
    robot = frictionless(atlas)

    def make():
        return Controller(robot, stiffness=300, observer_gain=5, threshold=11, kappa_eps=kappa_eps)

    ctrl = make()
    plant = settled_plant(robot, robot.home)
    ref = Reference.hold(robot.home)
    for k in range(300):
        m = plant.measure()
        if k % 50 == 25:
            before = ctrl.observer_state
            arr = np.array(getattr(m, field), dtype=float)
            arr[-1] = value
            cmd = ctrl.step(m._replace(**{field: arr}), ref)
            assert cmd.mode == "fault" and f"measurement {field}" in cmd.fault, cmd.fault
            np.testing.assert_array_equal(ctrl.observer_state, before)  # frozen exactly
        else:
            cmd = ctrl.step(m, ref)
            assert cmd.fault == "" and not cmd.collision
        plant.step(cmd.tau)
    mine, fresh = detected_as_by_a_fresh_controller(plant, ctrl, make)
    assert mine is not None and mine == fresh, (mine, fresh)


@pytest.mark.parametrize("kappa_eps", [0, 1])
def test_an_invalid_observer_state_is_reported_in_every_command_until_reset(atlas, kappa_eps):
    # the bounds make a non-finite observer state unreachable from inputs; a numerical blow-up is injected
    ctrl = Controller(atlas, kappa_eps=kappa_eps, reaction="none")
    ref = Reference.hold(atlas.home)
    ctrl.step(good(atlas, 0), ref)
    ctrl.observer.residual[3] = np.nan
    for k in range(1, 20):
        q = atlas.home + 0.01 * k
        cmd = ctrl.step(good(atlas, k, q=q), ref)
        assert cmd.mode == "fault" and "detection is off until reset()" in cmd.fault
        assert cmd.fault_code == _k.OBSERVER_INVALID
        assert cmd.collision  # never "no collision" from an invalid residual
        np.testing.assert_allclose(cmd.tau, atlas.compute_gravity(q), atol=1e-9)  # at the current position
    assert ctrl.observer_invalid
    ctrl.reset()  # the documented recovery
    cmd = ctrl.step(good(atlas, 100), ref)
    assert cmd.fault == "" and not cmd.collision and not ctrl.observer_invalid


# ---------------------------------------------------------------- finding 3
@pytest.mark.parametrize("field", ["q_d", "dq_d", "ddq_d"])
def test_the_reference_shape_is_checked(atlas, field):
    ctrl = Controller(atlas)
    ref = Reference.hold(atlas.home)._replace(**{field: np.zeros(3)})
    with pytest.raises(SignalError, match=rf"reference {field} must be a real vector of shape \(7,\); got shape") as e:
        ctrl.step(good(atlas), ref)
    assert e.value.signal == f"reference {field}"
    np.testing.assert_array_equal(ctrl.observer_state, np.zeros((6, atlas.n)))


# ---------------------------------------------------------------- finding 4
@pytest.mark.parametrize(
    "field, value, message",
    [
        (
            "gravity",
            np.array([0.0, -9.81]),
            r"measurement gravity must be a real vector of shape \(3,\); got shape \(2,\)",
        ),
        ("gravity", np.array([[0.0, 0.0, -9.81]]), r"measurement gravity .* got shape \(1, 3\)"),
        ("q", np.zeros(6), r"measurement q must be a real vector of shape \(7,\); got shape \(6,\)"),
        ("q", np.zeros(7, dtype=complex), r"measurement q .* got dtype complex128 \(complex, bool, str and object"),
        ("dq", np.array(["0"] * 7), r"measurement dq .* got dtype <U1"),
        ("tau_m", np.array([None] * 7), r"measurement tau_m .* got dtype object"),
        ("wrench", np.zeros(6, dtype=bool), r"measurement wrench .* got dtype bool"),
        ("t", "0.0", r"measurement t must be a real number \[s\]; got str"),
        ("t", None, r"measurement t must be a real number \[s\]; got NoneType"),
    ],
)
def test_wrong_types_and_shapes_raise_a_package_error_naming_the_signal(atlas, field, value, message):
    ctrl = Controller(atlas)
    ref = Reference.hold(atlas.home)
    ctrl.step(good(atlas, 0), ref)
    before = ctrl.observer_state
    with pytest.raises(SignalError, match=message):
        ctrl.step(good(atlas, 1)._replace(**{field: value}), ref)
    np.testing.assert_array_equal(ctrl.observer_state, before)
    assert ctrl.step(good(atlas, 1), ref).fault == ""  # nothing of the raised tick stayed behind


def test_lists_are_converted_and_a_non_measurement_raises(atlas):
    a, b = Controller(atlas), Controller(atlas)
    ref = Reference.hold(atlas.home)
    m = good(atlas)
    listed = Measurement(0, *(v.tolist() for v in m[1:]))
    np.testing.assert_array_equal(a.step(listed, Reference(*(v.tolist() for v in ref))).tau, b.step(m, ref).tau)
    with pytest.raises(SignalError, match=r"measurement must be a Measurement\(t, q, dq, tau_m, wrench, gravity\)"):
        a.step(m[:5], ref)  # type: ignore[arg-type]
    with pytest.raises(SignalError, match=r"reference must be a Reference\(q_d, dq_d, ddq_d\); got float"):
        a.step(m, 1.0)  # type: ignore[arg-type]


# ---------------------------------------------------------------- finding 5
def test_torque_is_bounded_by_the_effort_limits_and_saturation_is_reported(atlas):
    limit = atlas.effort_limit
    ctrl = Controller(atlas, stiffness=300)
    q_d = atlas.home.copy()
    q_d[0] += 0.5  # 300 Nm/rad x 0.5 rad = 150 Nm asked of a joint limited to 87 Nm
    cmd = ctrl.step(good(atlas), Reference.hold(q_d))
    assert cmd.fault == "" and cmd.saturated == (0,)
    assert cmd.tau[0] == limit[0]
    # a +10 rad glitch on q1 (it gave -3000 Nm) and q = 1e300 (3e302 Nm) are faults with bounded torque
    for q in (atlas.home + np.eye(atlas.n)[0] * 10.0, np.full(atlas.n, 1e300)):
        cmd = ctrl.step(good(atlas, ctrl.timing.n_periods + 1, q=q), Reference.hold(atlas.home))
        assert cmd.mode == "fault" and "measurement q[0]" in cmd.fault and "position_margin" in cmd.fault
        assert np.all(np.abs(cmd.tau) <= limit)
    # explicit limits and the opt-out
    assert np.all(Controller(atlas, torque_limit=10.0).torque_limit == 10.0)
    assert np.all(np.isinf(Controller(atlas, torque_limit=None).torque_limit))
    with pytest.raises(ConfigError, match="torque_limit must be 'model', None or a positive value; got 'max'"):
        Controller(atlas, torque_limit="max")


def test_torque_rate_limit_bounds_the_change_per_tick(atlas):
    rate = 2000.0  # [Nm/s] -> 2 Nm per 1 ms tick
    ctrl = Controller(atlas, stiffness=300, torque_rate_limit=rate)
    ref = Reference.hold(atlas.home)
    first = ctrl.step(good(atlas, 0), ref)  # the first command is not rate limited
    q_d = atlas.home + 0.05
    taus = [first.tau] + [ctrl.step(good(atlas, k), Reference.hold(q_d)).tau for k in range(1, 20)]
    steps = np.abs(np.diff(taus, axis=0))
    assert steps.max() <= rate * DT * (1 + 1e-12)  # tolerance: one rounding of prev + step
    assert steps.max() >= rate * DT * (1 - 1e-12)  # and it did bind (15 Nm asked at once)


def test_a_robot_without_effort_limits_warns_and_can_be_given_one(atlas):
    robot = atlas.copy()
    robot.pin_model.effortLimit = np.full(robot.n, np.inf)
    with pytest.warns(UserWarning, match=r"no finite positive effort limit for joint\(s\) \['l_arm_shz'"):
        ctrl = Controller(robot)
    assert np.all(np.isinf(ctrl.torque_limit))
    assert np.all(Controller(robot, torque_limit=50.0).torque_limit == 50.0)


# ---------------------------------------------------------------- finding 6
@pytest.mark.parametrize("dtype", [np.float32, np.int64, "list"])
def test_other_dtypes_are_converted_once_and_give_the_same_command(atlas, dtype):
    # the tick takes contiguous float64 vectors only; anything else is converted before the call (never a
    # silent reinterpretation of the memory, never a different result)
    ctrl, ref_ctrl = Controller(atlas), Controller(atlas)
    ref = Reference.hold(atlas.home)
    for k in range(3):
        m = good(atlas, k, q=np.round(atlas.home, 0), tau_m=np.round(atlas.compute_gravity(atlas.home)))
        conv = Measurement(m.t, *(v.tolist() if dtype == "list" else v.astype(dtype) for v in m[1:]))
        exact = Measurement(m.t, *(np.asarray(v, dtype=float) for v in conv[1:]))
        np.testing.assert_array_equal(ctrl.step(conv, ref).tau, ref_ctrl.step(exact, ref).tau)
    with pytest.raises(TypeError):  # the core itself refuses them (the Controller converts first)
        ctrl._core.update(0.01, *(np.asarray(v, dtype=np.float32) for v in good(atlas)[1:]), *ref)


# ---------------------------------------------------------------- finding 7
@pytest.mark.parametrize("t", [np.nan, 0.002, 0.0015, -1.0])
def test_nan_repeated_or_backwards_time_stamps_are_faults(atlas, t):
    ctrl = Controller(atlas)
    ref = Reference.hold(atlas.home)
    for k in range(3):
        ctrl.step(good(atlas, k), ref)
    before = ctrl.observer_state
    cmd = ctrl.step(good(atlas, t=t), ref)
    assert cmd.mode == "fault" and "measurement t" in cmd.fault
    np.testing.assert_array_equal(ctrl.observer_state, before)
    assert ctrl.step(good(atlas, 3), ref).fault == ""


def test_the_observer_integrates_the_measured_period_within_its_band(atlas):
    # a constant external torque seen through a jittery clock: the residual follows the discrete law
    # r_k = r_(k-1) + k_o h_k (tau_ext - r_(k-1)) with h_k the measured period clipped to [0.5, 2] dt
    k_o = 20.0
    ctrl = Controller(atlas, observer_gain=k_o, threshold=None)
    ref = Reference.hold(atlas.home)
    tau_ext = np.linspace(-3.0, 3.0, atlas.n)
    g = atlas.compute_gravity(atlas.home)
    rng = np.random.default_rng(4)
    periods = rng.uniform(0.6, 1.4, 200) * DT
    periods[[50, 120]] = 7 * DT  # two stalls: clipped to 2 dt
    periods[80] = 0.1 * DT  # a burst: clipped to 0.5 dt
    t, r = 0.0, np.zeros(atlas.n)
    ctrl.step(good(atlas, t=t, tau_m=g - tau_ext), ref)  # at rest: tau_m - g = -tau_ext
    for h in periods:
        t += h
        cmd = ctrl.step(good(atlas, t=t, tau_m=g - tau_ext), ref)
        r = r + k_o * np.clip(h, 0.5 * DT, 2 * DT) * (tau_ext - r)
        # tolerance: round-off of t and of the integral over 200 ticks
        np.testing.assert_allclose(cmd.residual, r, rtol=1e-9, atol=1e-10)
    timing = ctrl.timing
    assert timing.n_periods == 200 and timing.clipped == 3 and timing.band == (0.5 * DT, 2 * DT)
    assert timing.max_period == pytest.approx(7 * DT) and timing.min_period == pytest.approx(0.1 * DT)
    assert timing.mean_period == pytest.approx(periods.mean())


def test_plausibility_bounds_are_named_settable_and_let_sensor_noise_through(atlas):
    b = InputBounds(velocity_factor=2.0, max_force=100.0)
    ctrl = Controller(atlas, input_bounds=b)
    ref = Reference.hold(atlas.home)
    cmd = ctrl.step(good(atlas, wrench=np.array([0.0, 150.0, 0.0, 0.0, 0.0, 0.0])), ref)
    assert cmd.fault == "measurement wrench[1] = 150 N outside the plausible [-100, 100] N (InputBounds.max_force)"
    bounds = ctrl.signal_bounds
    np.testing.assert_array_equal(bounds["dq"][1], 2.0 * atlas.velocity_limit)
    with pytest.raises(ConfigError, match="InputBounds.max_force must be a finite positive number; got -1"):
        InputBounds(max_force=-1)
    # 30x the paper's sensor noise on every signal stays inside the default bounds
    ctrl = Controller(atlas)
    rng = np.random.default_rng(0)
    for k in range(200):
        u = lambda n, level: rng.uniform(-30 * level, 30 * level, n)  # noqa: E731
        m = good(
            atlas,
            k,
            q=atlas.home + u(7, 3.4e-4),
            dq=u(7, 5.5e-2),
            tau_m=atlas.compute_gravity(atlas.home) + u(7, 7.3e-2),
            wrench=np.concatenate([u(3, 2.3), u(3, 0.23)]),
            gravity=np.array([0.0, 0.0, -9.81]) + u(3, 2e-4),
        )
        assert ctrl.step(m, ref).fault == ""


def test_read_only_and_strided_float64_inputs_are_taken_as_they_are(atlas):
    a, b = Controller(atlas), Controller(atlas)
    ref = Reference.hold(atlas.home)
    for k in range(3):
        m = good(atlas, k)
        wide = np.zeros((atlas.n, 2))
        wide[:, 0] = m.q
        odd = m._replace(q=wide[:, 0], dq=m.dq.copy(), tau_m=m.tau_m.copy())  # a strided view
        odd.dq.flags.writeable = False
        odd.tau_m.flags.writeable = False
        np.testing.assert_array_equal(a.step(odd, ref).tau, b.step(m, ref).tau)


def test_the_supervisor_logs_an_invalid_observer_as_a_fault_not_a_collision(atlas):
    from reflexarm.control import ModeSupervisor

    sup = ModeSupervisor(Controller(atlas, threshold=11.0), mode="precise_stiff")
    ref = Reference.hold(atlas.home)
    sup.step(good(atlas, 0), ref)
    sup.controller.observer.residual[0] = np.inf
    assert sup.step(good(atlas, 1), ref).collision
    assert [(x.to_mode, x.cause) for x in sup.transitions] == [("precise_stiff", "task"), ("fault", "fault")]


def test_float64_arrays_with_an_equal_but_distinct_dtype_object_take_the_fast_path(atlas):
    # arrays made by a numba function loaded from its on-disk cache (the plant's) carry an unpickled float64 dtype
    import pickle

    f64 = pickle.loads(pickle.dumps(np.dtype(np.float64)))
    assert f64 is not np.dtype(np.float64)
    ctrl = Controller(atlas)
    ref = Reference.hold(atlas.home)
    ctrl.step(good(atlas, 0), ref)  # the first tick checks the types
    converted = []
    convert = ctrl._step_converted  # white box: count the ticks that take the conversion path

    def counting(m: Measurement, r: Reference):  # type: ignore[no-untyped-def]
        converted.append(m.t)
        return convert(m, r)

    ctrl._step_converted = counting  # type: ignore[method-assign]
    for k in range(1, 4):
        m = Measurement(k * DT, *(np.asarray(v, dtype=f64) for v in good(atlas, k)[1:]))
        assert m.q.dtype is not np.dtype(np.float64)
        assert ctrl.step(m, ref).fault == ""
    ctrl.step(good(atlas, 4)._replace(q=atlas.home.astype(np.float32)), ref)
    assert converted == [4 * DT]  # only the float32 tick was converted


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            dict(observer_gain=600.0),
            r"observer_gain \* dt \* period_band\[1\] must be < 1 .* got 600.0 1/s \* 0.001 s \* 2.0",
        ),
        (dict(period_band=(1.5, 2.0)), r"period_band must satisfy 0 < low <= 1 <= high < inf; got \(1.5, 2.0\)"),
        (dict(period_band=3.0), r"period_band must be \(low, high\) multiples of dt; got 3.0"),
        (dict(input_bounds={"max_force": 1.0}), "input_bounds must be an InputBounds; got dict"),
        (dict(torque_rate_limit=-1.0), "torque_rate_limit must be positive"),
    ],
)
def test_contract_parameters_are_checked(atlas, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        Controller(atlas, **kwargs)


# ---------------------------------------------------------------- one tick, two paths (issue 10)
# Controller.step reads a Measurement and a Reference of float time and plain float64 arrays in the C++ core
# (step_signals); every other input takes the Python path (unpack, convert once, or SignalError). Both paths
# must give the same Command, bit for bit: the same float64 values enter the same C++ tick.
class _StampedMeasurement(Measurement):
    """A user's subclass of Measurement (a NamedTuple subclass is still a tuple)."""

    @property
    def stamp_ms(self) -> float:
        return 1e3 * self.t


class _TaggedArray(np.ndarray):
    """A user's ndarray subclass (read through the buffer protocol, not from the array's fields)."""


def _each_vector(m: Measurement, r: Reference, f) -> tuple[Measurement, Reference]:  # type: ignore[no-untyped-def]
    return Measurement(m.t, *(f(v) for v in m[1:])), Reference(*(f(v) for v in r))


def _read_only(v: np.ndarray) -> np.ndarray:
    out = v.copy()
    out.flags.writeable = False
    return out


EQUIVALENT_INPUTS = {
    "Measurement subclass": lambda m, r: (_StampedMeasurement(*m), r),
    "plain tuples": lambda m, r: (tuple(m), tuple(r)),
    "lists": lambda m, r: _each_vector(m, r, lambda v: v.tolist()),
    "numpy.float64 t": lambda m, r: (m._replace(t=np.float64(m.t)), r),
    "0-d array t": lambda m, r: (m._replace(t=np.array(m.t)), r),
    "float subclass t": lambda m, r: (m._replace(t=type("Stamp", (float,), {})(m.t)), r),
    "big-endian float64": lambda m, r: _each_vector(m, r, lambda v: v.astype(">f8")),
    "ndarray subclass": lambda m, r: _each_vector(m, r, lambda v: v.copy().view(_TaggedArray)),
    "memoryview": lambda m, r: _each_vector(m, r, memoryview),
    "read-only arrays": lambda m, r: _each_vector(m, r, _read_only),
    "strided views": lambda m, r: _each_vector(m, r, lambda v: np.repeat(v, 2)[::2]),
}


def _ticks(robot) -> list[tuple[Measurement, Reference]]:  # type: ignore[no-untyped-def]
    """Plain ticks, a fault (NaN dq), then a 40 Nm push on joint 2 that crosses the 11 Nm threshold."""
    ref = Reference(robot.home.copy(), np.zeros(robot.n), np.zeros(robot.n))
    out = []
    for k in range(14):
        m = good(robot, k)
        if k == 4:
            m = m._replace(dq=np.full(robot.n, np.nan))
        if k >= 6:
            tau_m = m.tau_m.copy()
            tau_m[1] += 40.0
            m = m._replace(tau_m=tau_m)
        out.append((m, ref))
    return out


def _assert_same_command(got, want, where: str) -> None:  # type: ignore[no-untyped-def]
    assert type(got) is type(want), where
    np.testing.assert_array_equal(got.tau, want.tau, err_msg=f"{where}: tau")  # exact: the same tick
    np.testing.assert_array_equal(got.residual, want.residual, err_msg=f"{where}: residual")
    assert got[2:] == want[2:], where


@pytest.mark.parametrize("variant", list(EQUIVALENT_INPUTS))
def test_every_input_form_gives_the_same_command_as_plain_float64_arrays(atlas, variant):
    # observer_gain 50 1/s: the push crosses the threshold within a few ticks (event path); the NaN is a fault
    make = lambda: Controller(atlas, observer_gain=50.0, threshold=11.0, reaction="gravity")  # noqa: E731
    ctrl, plain = make(), make()
    modes, collisions = set(), []
    for k, (m, r) in enumerate(_ticks(atlas)):
        want = plain.step(m, r)
        _assert_same_command(ctrl.step(*EQUIVALENT_INPUTS[variant](m, r)), want, f"{variant}, tick {k}")
        modes.add(want.mode)
        collisions.append(want.collided_joints)
    # the sequence did go through the plain, fault and collision paths
    assert {"compliant", "fault", "gravity_compensation"} <= modes
    assert (1,) in collisions
    np.testing.assert_array_equal(ctrl.observer_state, plain.observer_state)


def test_integer_time_stamps_give_the_same_command_as_float_ones(atlas):
    # dt = 1 s (observer_gain * dt * period_band[1] = 0.8 < 1): integer stamps; a stiffness whose law is stable at 1 s
    make = lambda: Controller(atlas, dt=1.0, observer_gain=0.4, stiffness=1e-4)  # noqa: E731
    ctrl, plain = make(), make()
    ref = Reference.hold(atlas.home)
    for k in range(6):
        m = good(atlas, k, t=float(k))
        stamp = k if k % 2 else np.int64(k)  # a Python int and a numpy integer in turn
        _assert_same_command(ctrl.step(m._replace(t=stamp), ref), plain.step(m, ref), f"tick {k}")


@pytest.mark.parametrize(
    "t, message",
    [
        (True, r"measurement t must be a real number \[s\]; got bool"),
        (np.array([0.0]), r"measurement t must be a real number \[s\]; got float64 array of shape \(1,\)"),
        (1j, r"measurement t must be a real number \[s\]; got complex"),
    ],
)
def test_a_time_stamp_that_is_not_a_real_number_raises_as_before(atlas, t, message):
    ctrl = Controller(atlas)
    ref = Reference.hold(atlas.home)
    ctrl.step(good(atlas, 0), ref)
    before = ctrl.observer_state
    with pytest.raises(SignalError, match=message) as e:
        ctrl.step(good(atlas, 1, t=t), ref)
    assert e.value.signal == "measurement t"
    np.testing.assert_array_equal(ctrl.observer_state, before)


@pytest.mark.parametrize("field, n", [("q", 6), ("wrench", 5), ("q_d", 8)])
@pytest.mark.parametrize("form", ["float64 array", "list"])
def test_a_wrong_length_raises_the_same_error_on_both_paths(atlas, field, n, form):
    ctrl = Controller(atlas)
    m, r = good(atlas), Reference.hold(atlas.home)
    bad = np.zeros(n) if form == "float64 array" else [0.0] * n
    expected = atlas.n if field != "wrench" else 6
    signal = f"{'reference' if field == 'q_d' else 'measurement'} {field}"
    message = rf"^{signal} must be a real vector of shape \({expected},\); got shape \({n},\)$"
    with pytest.raises(SignalError, match=message):
        if field == "q_d":
            ctrl.step(m, r._replace(q_d=bad))
        else:
            ctrl.step(m._replace(**{field: bad}), r)
    np.testing.assert_array_equal(ctrl.observer_state, np.zeros((6, atlas.n)))


def test_each_command_owns_its_arrays(atlas):
    # users keep Commands: a later tick must never write into an earlier Command's tau or residual
    # at most 1 Nm of change per tick: the compensated push (kappa_eps = 1) is rate-limited (event path)
    ctrl = Controller(atlas, observer_gain=50.0, kappa_eps=1, switch_time=0.0, reaction="none", torque_rate_limit=1e3)
    kept, values = [], []
    for m, r in _ticks(atlas):
        cmd = ctrl.step(m, r)
        kept.append(cmd)
        values.append((cmd.tau.copy(), cmd.residual.copy()))
    assert any(c.saturated for c in kept) and any(not c.saturated and not c.fault for c in kept)  # both paths
    for k, (cmd, (tau, residual)) in enumerate(zip(kept, values, strict=True)):
        np.testing.assert_array_equal(cmd.tau, tau, err_msg=f"tick {k}: tau changed after later ticks")
        np.testing.assert_array_equal(cmd.residual, residual, err_msg=f"tick {k}: residual changed after later ticks")
        for a in (cmd.tau, cmd.residual):
            assert a.dtype == np.float64 and a.shape == (atlas.n,) and a.flags.owndata and a.flags.writeable
        assert not np.shares_memory(cmd.tau, cmd.residual)
    assert not np.shares_memory(kept[0].tau, kept[1].tau)
    assert len({id(c.tau) for c in kept}) == len(kept)
