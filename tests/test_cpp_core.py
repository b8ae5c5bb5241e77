"""The C++ core (``reflexarm._core``) against the plain numpy/Pinocchio oracle of ``controller_oracle.py``.

Both sides run the same seeded random sequence of measurements and references (with bad ticks). The Python
face, :class:`reflexarm.control.Controller`, is compared with the same oracle in test_controller_oracle.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import reflexarm._core as core

from controller_oracle import DT, N_TICKS, Oracle, core_controller, expected_text, ticks, with_springs
from reflexarm.control import Controller
from reflexarm.control import contract as _k
from reflexarm.signals import Measurement, Reference

# Tolerance 1e-9 [Nm, Nms]: both sides call the same Pinocchio functions; they differ only in summation order
# and in the eigen-decomposition of the modal damping (Jacobi rotations vs LAPACK), each ~1e-13 relative on
# quantities of ~1e2 Nm, and the observer's integral carries that over a few hundred ticks at most.
ATOL = 1e-9


def compare(k: int, want: dict, ctrl: Any, status: int) -> None:
    where = f"tick {k}"
    code = status if status < 0 else 0
    assert code == want["code"], f"{where}: code {code} ({ctrl.fault!r}), oracle {want['code']}"
    np.testing.assert_allclose(ctrl.tau, want["tau"], rtol=0, atol=ATOL, err_msg=f"{where}: tau")
    if code != _k.OBSERVER_INVALID:  # an invalid observer's state is part-way updated: not a number to compare
        np.testing.assert_allclose(ctrl.residual, want["residual"], rtol=0, atol=ATOL, err_msg=f"{where}: residual")
    assert ctrl.collision == want["collision"], where
    assert ctrl.command_mode == want["mode"], where
    np.testing.assert_array_equal(ctrl.collided.astype(bool), want["collided"], err_msg=f"{where}: collided")
    np.testing.assert_array_equal(ctrl.saturated.astype(bool), want["saturated"], err_msg=f"{where}: saturated")
    if want["fault"] is not None and code != _k.OBSERVER_INVALID:
        sig, idx, val, lo, hi = ctrl.fault_info
        assert (sig, idx) == tuple(want["fault"][1:3]), where
        np.testing.assert_allclose([val, lo, hi], want["fault"][3:], rtol=1e-12, err_msg=where)
        assert ctrl.fault == expected_text(want["fault"]), where
    if code == 0:
        assert ctrl.fault == "", where


def run_both(robot, o: Oracle, ctrl: Any, **kw) -> list[int]:
    codes = []
    for k, args in ticks(robot, **kw):
        if k == 200 and o.reaction == "none":  # a kappa_eps switch mid-run, ramped over switch_time
            o.set_switches(1 - o.kappa_eps)
            ctrl.set_switches(kappa_eps=1 - ctrl.kappa_eps)
        want = o.step(*args)
        status = ctrl.update(*args)
        compare(k, want, ctrl, status)
        codes.append(want["code"])
    return codes


# ---------------------------------------------------------------------- tests
@pytest.mark.parametrize("kappa_f", [0, 1])
@pytest.mark.parametrize("kappa_eps", [0, 1])
@pytest.mark.parametrize("kappa_ext", [0, 1])
def test_tick_equals_oracle_for_every_switch_combination(atlas, kappa_f, kappa_eps, kappa_ext):
    o = Oracle(atlas, kappa_f=kappa_f, kappa_eps=kappa_eps, kappa_ext=kappa_ext, threshold=None, reaction="none",
               torque_rate_limit=3000.0 if kappa_f else None)  # fmt: skip
    codes = run_both(atlas, o, core_controller(core, atlas, o))
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]


@pytest.mark.parametrize("reaction", ["gravity", "compliant", "none"])
@pytest.mark.parametrize("detection_gain", [None, 30.0])
def test_detection_and_reaction_equal_oracle(atlas, reaction, detection_gain):
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=detection_gain,
               switch_time=0.0 if reaction == "compliant" else 0.1)  # fmt: skip
    ctrl = core_controller(core, atlas, o)
    run_both(atlas, o, ctrl, push=40.0)
    assert o.detected and ctrl.detected, "the 40 Nm push was not detected: the test would prove nothing"
    assert 0.1 < ctrl.first_time < N_TICKS * DT
    assert (
        ctrl.mode
        == o.mode
        == {"gravity": "gravity_compensation", "compliant": "compliant"}.get(
            reaction, "precise_ee_compliant" if o.kappa_eps else "compliant"
        )
    )
    o.reset()
    ctrl.reset()
    assert ctrl.mode == o.mode and not ctrl.detected and ctrl.kappa_eps == o.kappa_eps


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
def test_core_equals_python_controller(atlas, springs):
    """The same run through reflexarm.control.Controller (the face that will delegate to the core)."""
    atlas = with_springs(atlas) if springs else atlas
    kw = {"kappa_f": 1, "kappa_eps": 1, "kappa_ext": 1, "threshold": 11.0, "reaction": "gravity"}
    py = Controller(atlas, detection_observer_gain=30.0, torque_rate_limit=3000.0, **kw)
    o = Oracle(atlas, detection_observer_gain=30.0, torque_rate_limit=3000.0, **kw)
    ctrl = core_controller(core, atlas, o)
    for k, (t, *rest) in ticks(atlas, push=40.0):
        status = ctrl.update(t, *rest)
        cmd = py.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        where = f"tick {k}"
        np.testing.assert_allclose(ctrl.tau, cmd.tau, rtol=0, atol=ATOL, err_msg=where)
        np.testing.assert_allclose(ctrl.residual, cmd.residual, rtol=0, atol=ATOL, err_msg=where)
        assert (ctrl.fault, ctrl.command_mode, ctrl.collision) == (cmd.fault, cmd.mode, cmd.collision), where
        assert (status if status < 0 else 0) == cmd.fault_code, where
    assert py.detector is not None and ctrl.first_time == py.detector.first_time


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
