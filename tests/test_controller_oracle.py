"""reflexarm.control.Controller (the Python face of the C++ core) against the plain numpy/Pinocchio oracle.

Every switch combination (kappa_f, kappa_eps, kappa_ext = DC/EFC, the modal damping updated every tick, every 3rd
(its computation spread over 3 ticks) or every 10th (over 4)), a reset while a damping computation is under way,
detection (12) with one or two observers, each reaction (13), the faults of the input contract, the
invalid-observer latch and the joint springs: the commands are compared tick by tick over the seeded run of
``controller_oracle.ticks`` (with its NaN, implausible, repeated-stamp, gravity and late ticks).
"""

from __future__ import annotations

import numpy as np
import pytest

from controller_oracle import DT, N_TICKS, Oracle, expected_text, ticks, with_springs
from reflexarm.control import Controller
from reflexarm.control import contract as _k
from reflexarm.signals import Command, Measurement, Reference

# Tolerance 1e-9 [Nm, Nms]: the same Pinocchio functions on both sides; summation order and the modal damping's
# eigen-decomposition (Jacobi rotations in C++, LAPACK in the oracle) differ by ~1e-13 relative on ~1e2 Nm, which
# the observer's integral carries over a few hundred ticks at most.
ATOL = 1e-9


def controller_like(robot, o: Oracle) -> Controller:
    """A Controller with the oracle's settings (torque_limit: the model's effort limits, as the oracle)."""
    return Controller(
        robot,
        stiffness=o.stiffness,
        damping_ratio=o.damping_ratio,
        observer_gain=o.observer_gain,
        detection_observer_gain=o.detection_observer_gain,
        threshold=o.threshold,
        reaction=o.reaction,
        kappa_f=o.kappa_f,
        kappa_eps=o.kappa_eps,
        kappa_ext=o.kappa_ext,
        residual_limit=o.residual_limit,
        switch_time=o.switch_time,
        dt=DT,
        damping_update_period=o.damping_update_period,
        torque_rate_limit=o.torque_rate_limit,
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


def run_both(robot, o: Oracle, ctrl: Controller, **kw) -> list[int]:
    codes = []
    for k, (t, *rest) in ticks(robot, **kw):
        if k == 200 and o.reaction == "none":  # a kappa_eps switch mid-run, ramped over switch_time
            o.set_switches(1 - o.kappa_eps)
            ctrl.set_switches(kappa_eps=1 - ctrl.kappa_eps)
        want = o.step(t, *rest)
        cmd = ctrl.step(Measurement(t, *rest[:5]), Reference(*rest[5:]))
        compare(k, want, cmd, ctrl, o)
        assert ctrl.mode == o.mode, f"tick {k}"
        codes.append(want["code"])
    return codes


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


@pytest.mark.parametrize("reaction", ["gravity", "compliant", "none"])
@pytest.mark.parametrize("detection_gain", [None, 30.0])
def test_detection_and_reaction_of_controller_equal_oracle(atlas, reaction, detection_gain):
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=detection_gain,
               switch_time=0.0 if reaction == "compliant" else 0.1)  # fmt: skip
    ctrl = controller_like(atlas, o)
    run_both(atlas, o, ctrl, push=40.0)
    assert o.detected and ctrl.detector is not None and ctrl.detector.detected, "the 40 Nm push went undetected"
    assert ctrl.detector.first_time is not None and 0.1 < ctrl.detector.first_time < N_TICKS * DT
    expected = {"gravity": "gravity_compensation", "compliant": "compliant"}
    assert ctrl.mode == o.mode == expected.get(reaction, "precise_ee_compliant" if o.kappa_eps else "compliant")
    assert ctrl.reacted == (reaction != "none")
    o.reset()
    ctrl.reset()
    assert ctrl.mode == o.mode and not ctrl.reacted and ctrl.kappa_eps == o.kappa_eps
    assert not ctrl.detector.detected and ctrl.detector.first_time is None


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
