"""reflexarm.control.replay: a whole log through the C++ core in one call, against Controller.step sample by sample.

The reference path is the Python face of the same controller (``Controller.step`` on every sample with a hold
at the measured position, as ``tune-thresholds`` replayed before): an independent driver of the core, whose
Command the replay must reproduce on every sample (residual, torque, detection flags, mode, faults), and
whose state after the log the replayed controller must have.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from reflexarm import load_robot
from reflexarm.control import MODES, Controller, replay
from reflexarm.errors import ConfigError, DataError
from reflexarm.signals import Measurement, Reference
from rpr_arm import rpr_urdf

#: The replay and the step loop run the same update() on the same numbers in the same order: they agree to
#: the bit; 1e-12 Nm is the bar the issue sets (far below any threshold).
TOL = 1e-12


@pytest.fixture(scope="module")
def atlas():
    return load_robot("atlas_v5_left_arm")


def _log(robot, N=3000, seed=0, bump=True):
    """A smooth motion with noisy velocities and torques (gravity + noise), a torque bump on joint 2 at 1.5 s."""
    rng = np.random.default_rng(seed)
    n = robot.n
    t = 0.5 + np.arange(N) * 1e-3
    q = robot.home + 0.2 * np.sin(np.outer(t, 0.5 + 0.3 * np.arange(n)))
    dq = np.gradient(q, t, axis=0) + 1e-3 * rng.standard_normal((N, n))
    tau = np.array([robot.compute_gravity(x) for x in q]) + 0.3 * rng.standard_normal((N, n))
    if bump:
        tau[1500:1700, 2] += 25.0
    wrench = rng.standard_normal((N, 6))
    return t, q, dq, tau, wrench


def _steps(ctrl, t, q, dq, tau, wrench):
    g = np.asarray(ctrl.robot.gravity, float)
    z = np.zeros(ctrl.n)
    w0 = np.zeros(6)
    out = []
    for k in range(t.size):
        w = w0 if wrench is None else wrench[k]
        out.append(ctrl.step(Measurement(float(t[k]), q[k], dq[k], tau[k], w, g), Reference(q[k], z, z)))
    return out


def _assert_same(res, cmds, n):
    np.testing.assert_allclose(res.residual, np.array([c.residual for c in cmds]), rtol=0, atol=TOL)
    np.testing.assert_allclose(res.tau, np.array([c.tau for c in cmds]), rtol=0, atol=TOL)
    np.testing.assert_array_equal(res.collision, [c.collision for c in cmds])
    over = np.zeros((len(cmds), n), dtype=bool)
    for k, c in enumerate(cmds):
        over[k, list(c.collided_joints)] = True
    np.testing.assert_array_equal(res.over, over)
    np.testing.assert_array_equal(res.modes, [c.mode for c in cmds])
    np.testing.assert_array_equal(res.fault_code, [c.fault_code for c in cmds])
    faults = [(float(res.t[k]), c.fault) for k, c in enumerate(cmds) if c.fault]
    assert res.fault_ticks == len(faults)
    assert list(res.faults) == faults[: len(res.faults)]


@pytest.mark.parametrize(
    ("kwargs", "with_wrench"),
    [
        (dict(threshold=None, reaction="none"), False),  # tune-thresholds' controller
        (dict(threshold=8.0, reaction="none", contact_geometry=None), False),
        (dict(threshold=8.0, reaction="gravity", kappa_ext=1, contact_geometry=None), True),  # EFC, a reaction
        (dict(threshold=8.0, detection_observer_gain=40.0, observer_discretization="exact", kappa_f=1), True),
    ],
)
def test_replay_is_step_sample_by_sample(atlas, kwargs, with_wrench):
    t, q, dq, tau, wrench = _log(atlas)
    w = wrench if with_wrench else None
    a, b = Controller(atlas, **kwargs), Controller(atlas, **kwargs)
    res = replay(a, t, q, dq, tau, w, torque=True)
    cmds = _steps(b, t, q, dq, tau, w)
    _assert_same(res, cmds, atlas.n)
    if kwargs["threshold"] is not None:
        assert res.collision.any() and len(res.events) >= 1
        assert res.events[0].t_start == b.detector.first_time == a.detector.first_time
        assert 2 in res.events[0].joints
        assert res.event is not None and res.event.to_dict() == b.event.to_dict()
    # both controllers are left in the same state: the next tick is the same
    nxt = [c.step(Measurement(t[-1] + 1e-3, q[-1], dq[-1], tau[-1], np.zeros(6), atlas.gravity),
                  Reference(q[-1], np.zeros(atlas.n), np.zeros(atlas.n))) for c in (a, b)]  # fmt: skip
    np.testing.assert_array_equal(nxt[0].residual, nxt[1].residual)
    np.testing.assert_array_equal(nxt[0].tau, nxt[1].tau)
    assert a.mode == b.mode and a.reacted == b.reacted


def test_rejected_samples_are_faults_as_in_step(atlas):
    t, q, dq, tau, _ = _log(atlas, N=600, bump=False)
    q[100, 3] = np.nan
    tau[200, 1] = 1e6  # beyond the torque bound
    dq[300:303, 0] = np.inf
    a, b = Controller(atlas, threshold=None, reaction="none"), Controller(atlas, threshold=None, reaction="none")
    res = replay(a, t, q, dq, tau, torque=True)
    cmds = _steps(b, t, q, dq, tau, None)
    _assert_same(res, cmds, atlas.n)
    assert res.fault_ticks == 5
    assert "q" in res.faults[0][1] and res.faults[0][0] == t[100]
    assert set(res.modes[[100, 200, 300]]) == {"fault"}
    assert MODES[res.mode[0]] == "compliant"


def test_bad_input_is_named(atlas):
    t, q, dq, tau, _ = _log(atlas, N=50, bump=False)
    ctrl = Controller(atlas, threshold=None, reaction="none")
    with pytest.raises(DataError, match=r"dq must have shape \(50, 7\) \(N samples x n joints\); got \(50, 6\)"):
        replay(ctrl, t, q, dq[:, :6], tau)
    with pytest.raises(DataError, match=r"wrench must have shape \(50, 6\)"):
        replay(ctrl, t, q, dq, tau, np.zeros((49, 6)))
    back = t.copy()
    back[20] = back[18]
    with pytest.raises(DataError, match=r"t must be strictly increasing; t\[20\] = .* <= t\[19\]"):
        replay(ctrl, back, q, dq, tau)
    nan_t = t.copy()
    nan_t[7] = np.nan
    with pytest.raises(DataError, match=r"t must be finite; t\[7\] = nan"):
        replay(ctrl, nan_t, q, dq, tau)
    with pytest.raises(DataError, match="t must have shape"):
        replay(ctrl, t[:0], q[:0], dq[:0], tau[:0])
    with pytest.raises(DataError, match="q must be an array of real numbers"):
        replay(ctrl, t, q.astype(complex), dq, tau)


def test_tuning_replay_residual_is_the_step_loop(atlas):
    """tune-thresholds' replay_residual (now one replay call) against its former per-sample loop."""
    from reflexarm.logs.robot_log import RobotLog
    from reflexarm.tuning.replay import ObserverSettings, replay_residual

    t, q, dq, tau, _ = _log(atlas, N=1500, bump=False)
    tau[400, 2] = 5e3  # beyond the torque bound: one rejected sample, counted, warned, its residual held
    log = RobotLog(t=t, q=q, dq=dq, tau=tau, source="synthetic")
    s = ObserverSettings(observer_gain=5.0, kappa_f=1)
    with pytest.warns(UserWarning, match="rejected 1 of 1500 samples"):
        rep = replay_residual(log, atlas, s)
    ctrl = Controller(
        atlas, observer_gain=5.0, threshold=None, reaction="none", kappa_f=1, dt=float(np.median(np.diff(t))),
        torque_limit=None,
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cmds = _steps(ctrl, t, q, dq, log.measured_torque, None)
    np.testing.assert_allclose(rep.residual, np.array([c.residual for c in cmds]), rtol=0, atol=TOL)
    assert rep.fault_ticks == 1 and rep.faults[0].startswith(f"t = {t[400]:.4f} s: ")


# ------------------------------------------------------------------------------------------ the residual-only path
#: The residual-only path sums the dynamics terms in another order than Pinocchio's rnea / computeCoriolisMatrix /
#: computeGeneralizedGravity (measured: g within 3e-14 Nm, C^T dq within 6e-15 Nm on the Atlas arm); the observers
#: filter these differences, so the residuals agree far below the issue's 1e-12 Nm bar (TOL).
SETUPS = [
    dict(threshold=None, reaction="none"),  # tune-thresholds' controller (Euler)
    dict(threshold=None, reaction="none", observer_discretization="exact", kappa_f=1),  # reflexarm detect's
    dict(threshold=None, reaction="none", kappa_ext=1, detection_observer_gain=40.0),  # EFC + detection observer
    dict(threshold=8.0, reaction="none", contact_geometry=None),  # a detector that never fires on this log
    dict(threshold=8.0, reaction="gravity", kappa_ext=1, contact_geometry=None, observer_discretization="exact"),
]


def _assert_same_detection(res, ref):
    """Everything the detection reads, res (residual-only) against ref (the full path or the step loop)."""
    np.testing.assert_allclose(res.residual, ref.residual, rtol=0, atol=TOL)
    for name in ("collision", "over", "mode", "fault_code"):
        np.testing.assert_array_equal(getattr(res, name), getattr(ref, name), err_msg=name)
    assert res.fault_ticks == ref.fault_ticks and res.faults == ref.faults
    assert _same_events(res.events, ref.events)


def _same_events(a, b):
    """The same crossings (samples, times, joints) with peaks within TOL."""
    if len(a) != len(b):
        return False
    return all(x[:5] == y[:5] and abs(x.peak - y.peak) <= TOL for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("kwargs", SETUPS)
@pytest.mark.parametrize("threads", [1, 2])
def test_residual_only_path_is_the_full_path(atlas, kwargs, threads):
    t, q, dq, tau, wrench = _log(atlas, bump=False)
    a, b, c = (Controller(atlas, **kwargs) for _ in range(3))
    fast = replay(a, t, q, dq, tau, wrench, threads=threads)
    full = replay(b, t, q, dq, tau, wrench, torque=True)
    assert fast.residual_only and fast.full_path_reason == "" and fast.tau is None
    assert not full.residual_only and full.full_path_reason == "the commanded torque is asked for"
    _assert_same_detection(fast, full)
    cmds = _steps(c, t, q, dq, tau, wrench)
    np.testing.assert_allclose(fast.residual, np.array([x.residual for x in cmds]), rtol=0, atol=TOL)
    assert fast.residual.std(axis=0).min() > 1e-3  # the residual moves: the comparison is not of zeros
    # the observers and the clock are left where the steps leave them: the next tick's residual is the same
    z = np.zeros(atlas.n)
    m = Measurement(t[-1] + 1e-3, q[-1], dq[-1], tau[-1] + 1.0, wrench[-1], atlas.gravity)
    nxt = [x.step(m, Reference(q[-1], z, z)) for x in (a, c)]
    np.testing.assert_allclose(nxt[0].residual, nxt[1].residual, rtol=0, atol=TOL)


@pytest.mark.parametrize("threads", [1, 2])
def test_residual_only_path_rejects_as_step(atlas, threads):
    t, q, dq, tau, _ = _log(atlas, N=600, bump=False)
    q[100, 3] = np.nan
    tau[200, 1] = 1e6  # beyond the torque bound
    dq[300:303, 0] = np.inf
    a, b = Controller(atlas, threshold=None, reaction="none"), Controller(atlas, threshold=None, reaction="none")
    res = replay(a, t, q, dq, tau, threads=threads)
    assert res.residual_only
    cmds = _steps(b, t, q, dq, tau, None)
    np.testing.assert_allclose(res.residual, np.array([c.residual for c in cmds]), rtol=0, atol=TOL)
    np.testing.assert_array_equal(res.fault_code, [c.fault_code for c in cmds])
    np.testing.assert_array_equal(res.modes, [c.mode for c in cmds])
    assert res.fault_ticks == 5 and [f for _, f in res.faults] == [c.fault for c in cmds if c.fault]


def test_a_detection_hands_the_log_to_the_full_path(atlas):
    """The reaction after a detection needs the command: the whole log runs on the full path, as Controller.step."""
    t, q, dq, tau, wrench = _log(atlas)
    kw = dict(threshold=8.0, reaction="gravity", kappa_ext=1, contact_geometry=None)
    a, b = Controller(atlas, **kw), Controller(atlas, **kw)
    res = replay(a, t, q, dq, tau, wrench, threads=2)
    assert not res.residual_only and res.full_path_reason.startswith("a detection")
    cmds = _steps(b, t, q, dq, tau, wrench)
    np.testing.assert_allclose(res.residual, np.array([c.residual for c in cmds]), rtol=0, atol=TOL)
    np.testing.assert_array_equal(res.modes, [c.mode for c in cmds])
    assert res.collision.any() and res.event is not None and res.event.to_dict() == b.event.to_dict()
    # a detection latched before the call: the full path at once
    again = replay(a, t + 10.0, q, dq, tau, wrench)
    assert not again.residual_only and again.full_path_reason == "a detection is latched in the controller"


def test_threads_must_be_one_or_two(atlas):
    t, q, dq, tau, _ = _log(atlas, N=20, bump=False)
    with pytest.raises(ConfigError, match="threads must be 1, 2 or None; got 3"):
        replay(Controller(atlas, threshold=None, reaction="none"), t, q, dq, tau, threads=3)


def test_tuning_and_detect_replay_take_the_residual_only_path(atlas, monkeypatch):
    """replay_residual (tune-thresholds, reflexarm detect) asks for no torque: the residual-only path runs."""
    import reflexarm.control
    from reflexarm.logs.robot_log import RobotLog
    from reflexarm.tuning.replay import ObserverSettings, replay_residual

    seen = []
    real = reflexarm.control.replay

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        seen.append(out.residual_only)
        return out

    monkeypatch.setattr(reflexarm.control, "replay", spy)
    t, q, dq, tau, _ = _log(atlas, N=500, bump=False)
    replay_residual(RobotLog(t=t, q=q, dq=dq, tau=tau, source="synthetic"), atlas, ObserverSettings())
    assert seen == [True]


@pytest.mark.parametrize("threads", [1, 2])
def test_residual_only_path_over_several_blocks(atlas, threads):
    """A log longer than the core's block (8192 samples): the blocks' terms (pipelined on two threads) line up with
    their samples, faults in later blocks included."""
    N = 20_000  # two whole blocks and a part
    t, q, dq, tau, wrench = _log(atlas, N=N, bump=False)
    tau[9000, 4] = 1e6  # a rejected sample in the second block
    q[16500, 0] = np.nan  # ... and in the third
    kw = dict(threshold=None, reaction="none", kappa_ext=1, observer_discretization="exact")
    fast = replay(Controller(atlas, **kw), t, q, dq, tau, wrench, threads=threads)
    full = replay(Controller(atlas, **kw), t, q, dq, tau, wrench, torque=True)
    assert fast.residual_only and fast.fault_ticks == 2
    _assert_same_detection(fast, full)


#: A revolute joint about a tilted axis, a prismatic joint along an unaligned axis, a revolute joint about a negative
#: axis after it: the residual-only path's world-frame pass covers more than the built-in arms' axis-aligned
#: revolute joints.
URDF_RPR = rpr_urdf(j1_axis="0.36 0 0.48", j3_axis="0 -1 0")


def _other_arm(name, tmp_path):
    if name == "rpr":
        path = tmp_path / "rpr.urdf"
        path.write_text(URDF_RPR)
        return load_robot(path, tip="l3")
    if name == "ur_like":
        from reflexarm.robots import write_ur_like_arm

        return load_robot(write_ur_like_arm(tmp_path), tip="tool0")
    return load_robot(name)


@pytest.mark.parametrize("name", ["panda", "iiwa14", "ur_like", "rpr"])
def test_residual_only_path_on_other_arms(name, tmp_path):
    """The world-frame terms (unaligned axes, a prismatic joint, negative axes, the wrist wrench) on other arms:
    the residual-only path against the full path (Pinocchio's rnea, Coriolis matrix, gravity, frame Jacobian)."""
    robot = _other_arm(name, tmp_path)
    t, q, dq, tau, wrench = _log(robot, N=1500, bump=False)
    kw = dict(threshold=None, reaction="none", kappa_ext=1, kappa_f=1)
    fast = replay(Controller(robot, **kw), t, q, dq, tau, wrench, threads=1)
    full = replay(Controller(robot, **kw), t, q, dq, tau, wrench, torque=True)
    assert fast.residual_only, fast.full_path_reason
    assert fast.fault_ticks == 0  # every sample passed the contract: the comparison is of accepted samples
    _assert_same_detection(fast, full)
    assert fast.residual.std(axis=0).min() > 1e-3
