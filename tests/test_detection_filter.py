"""The detection residual's second stage (``Controller(detection_filter_gain=K_f)``; issue 15's faster detection):
the detector looks at the detection residual filtered once more, a second-order filter of the external torque.

Checked against the plain oracle (``tests/controller_oracle.py``) tick by tick, with and without a detection
observer, both observer forms, with a detection and each reaction after it; against the first-order residual
filtered by scipy; the residual-only replay against the tick; the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from controller_oracle import DT, Oracle, core_controller, ticks
from reflexarm import load_robot
from reflexarm.control import Controller, replay
from reflexarm.control import contract as _k
from reflexarm.control._setup import load_core
from reflexarm.errors import ConfigError
from test_controller_oracle import REACTION_PARAMS, RUN_TICKS, SHORT, controller_like, run_both

PANDA = load_robot("panda")

#: [Nm] the stage filtered here against scipy's lfilter of the first-order residual: both evaluate
#: r_f = b r_f + (1 - b) r in double precision in another order (~1e-16 relative per tick on ~10 Nm residuals).
LFILTER_ATOL = 1e-12
#: [Nm] a push's response as the difference of two runs: each run's residual carries ~10 Nm of velocity noise whose
#: round-off (~1e-15 relative per tick) does not cancel exactly.
PUSH_ATOL = 1e-9
#: [Nm] the residual-only replay against the tick: the dynamics terms computed another way (ResidualTerms) differ by
#: ~1e-14 Nm (measured up to 7e-15 here); the bar test_replay.py sets for the replay, far below any threshold
REPLAY_ATOL = 1e-12


@pytest.mark.parametrize("detection_gain", [None, 200.0])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_second_stage_equals_oracle(atlas, detection_gain, discretization):
    """K_f = 150 1/s on the detection observer (or, without one, on the first observer) over the seeded run with its
    rejected ticks and the clipped late period; the oracle with another K_f must differ, so the comparison sees the
    stage (the code before this change has no stage: its residual is the oracle's r_obs, which also differs)."""
    gain = detection_gain if discretization == "exact" or detection_gain is None else 100.0
    kw = {"threshold": None, "reaction": "none", "detection_observer_gain": gain, "discretization": discretization}
    o = Oracle(atlas, detection_filter_gain=150.0, **kw)
    codes = run_both(atlas, o, _like(atlas, o))
    assert sorted(set(codes)) == [_k.TIME_NOT_INCREASING, _k.OUT_OF_BOUNDS, _k.NON_FINITE, 0]
    for other in (100.0, None):
        broken = Oracle(atlas, detection_filter_gain=other, **kw)
        with pytest.raises(AssertionError, match="residual"):
            run_both(atlas, broken, _like(atlas, Oracle(atlas, detection_filter_gain=150.0, **kw)))


@pytest.mark.parametrize("reaction", REACTION_PARAMS)
def test_detection_and_reaction_on_the_second_stage_equal_oracle(atlas, reaction):
    """A 40 Nm push from tick 100 detected on the staged residual (K_o,det 30, K_f 60 1/s): the detection tick, each
    reaction's phases and the event record (its residual, peak and re-crossings are the staged residual's) equal
    the oracle's on every tick."""
    o = Oracle(atlas, kappa_eps=1, kappa_ext=1, reaction=reaction, detection_observer_gain=30.0,
               detection_filter_gain=60.0, settings=SHORT, discretization="exact")  # fmt: skip
    ctrl = _like(atlas, o)
    run_both(atlas, o, ctrl, push=40.0, n_ticks=RUN_TICKS)
    assert ctrl.event is not None and o.event is not None


def test_second_stage_is_the_first_order_residual_filtered_once_more():
    """A Panda log (its velocity noise alone moves the residual by ~10 Nm) with a 40 Nm push on joint 2 from tick 100:
    the staged residual equals scipy's first-order filter (exact form, b = e^{-K_f dt}) of the unstaged one from 0
    (LFILTER_ATOL). The push's own response, the run with it less the same run without it (the observers are
    linear in tau_m), is the analytic one: 40 (1 - a^m) for the first order and, K_o = K_f (a = b),
    40 (1 - a^m - m (1 - a) a^m) for the stage, m ticks into the push."""
    t, q, dq, tau = _panda_log()
    _, _, _, tau0 = _panda_log(push=0.0)
    kw = {"threshold": None, "reaction": "none", "detection_observer_gain": 200.0, "observer_discretization": "exact"}
    first, first0 = (replay(Controller(PANDA, **kw), t, q, dq, x).residual for x in (tau, tau0))
    staged, staged0 = (replay(Controller(PANDA, detection_filter_gain=200.0, **kw), t, q, dq, x).residual
                       for x in (tau, tau0))  # fmt: skip
    b = math.exp(-200.0 * DT)
    np.testing.assert_allclose(staged, lfilter([1.0 - b], [1.0, -b], first, axis=0), rtol=0, atol=LFILTER_ATOL)
    m = np.arange(1, 300)
    sign = np.sign(first[150, 1] - first0[150, 1])
    np.testing.assert_allclose(sign * (first - first0)[99 + m, 1], 40.0 * (1.0 - b**m), rtol=0, atol=PUSH_ATOL)
    np.testing.assert_allclose(sign * (staged - staged0)[99 + m, 1], 40.0 * (1.0 - b**m - m * (1.0 - b) * b**m),
                               rtol=0, atol=PUSH_ATOL)  # fmt: skip
    np.testing.assert_allclose((staged - staged0)[:, [0, 2, 3, 4, 5, 6]], 0.0, atol=PUSH_ATOL)


def test_residual_only_replay_equals_the_tick_with_the_stage():
    """replay() takes the residual-only path (no torque asked) on one and two threads; each equals Controller.step
    tick by tick with the stage (the shared per-joint observer step and the stage in it), to the terms' rounding
    (REPLAY_ATOL)."""
    t, q, dq, tau = _panda_log()
    kw = {"threshold": None, "reaction": "none", "detection_observer_gain": 100.0, "detection_filter_gain": 300.0,
          "observer_discretization": "exact"}  # fmt: skip
    from reflexarm.signals import Measurement, Reference

    ctrl = Controller(PANDA, **kw)
    g, w = PANDA.gravity, np.zeros(6)
    z = np.zeros(PANDA.n)
    by_tick = np.array([ctrl.step(Measurement(tk, qk, vk, uk, w, g), Reference(qk, z, z)).residual
                        for tk, qk, vk, uk in zip(t, q, dq, tau, strict=True)])  # fmt: skip
    for threads in (1, 2):
        rep = replay(Controller(PANDA, **kw), t, q, dq, tau, threads=threads)
        assert rep.residual_only
        np.testing.assert_allclose(rep.residual, by_tick, rtol=0, atol=REPLAY_ATOL)


def test_the_controller_s_detection_residual_is_the_staged_one():
    """``Controller.detection_residual`` is what the detector looks at: with the stage r_f (the Command's residual),
    not the detection observer's own (it was the observer's before the stage existed)."""
    t, q, dq, tau = _panda_log(seconds=0.15)
    from reflexarm.signals import Measurement, Reference

    z, w = np.zeros(PANDA.n), np.zeros(6)
    for stage in (None, 50.0):
        ctrl = Controller(PANDA, detection_observer_gain=100.0, detection_filter_gain=stage, threshold=None,
                          reaction="none", observer_discretization="exact")  # fmt: skip
        for tk, qk, vk, uk in zip(t, q, dq, tau, strict=True):
            cmd = ctrl.step(Measurement(tk, qk, vk, uk, w, PANDA.gravity), Reference(qk, z, z))
        np.testing.assert_array_equal(ctrl.detection_residual, cmd.residual)
        assert ctrl.detection_observer is not None
        same = np.array_equal(ctrl.detection_residual, ctrl.detection_observer.residual)
        assert same == (stage is None)


def test_reset_starts_the_stage_from_zero():
    """After reset() the staged residual of the same log is the same as a fresh controller's (the stage's state is
    zeroed with the observers'); without zeroing it the second run would start from the first run's last value."""
    t, q, dq, tau = _panda_log()
    kw = {"threshold": None, "reaction": "none", "detection_observer_gain": 100.0, "detection_filter_gain": 50.0,
          "observer_discretization": "exact"}  # fmt: skip
    ctrl = Controller(PANDA, **kw)
    first = replay(ctrl, t, q, dq, tau).residual
    assert np.max(np.abs(first[-1])) > 10.0  # the push is on at the end: a state a reset must clear
    ctrl.reset()
    np.testing.assert_array_equal(replay(ctrl, t, q, dq, tau).residual, first)


def test_bad_filter_gain_is_refused():
    for bad in (0.0, -5.0, float("nan"), float("inf"), [100.0, 200.0]):
        with pytest.raises(ConfigError, match="detection_filter_gain"):
            Controller(PANDA, detection_observer_gain=100.0, detection_filter_gain=bad)
    core = load_core()
    o = Oracle(PANDA, detection_filter_gain=100.0)
    p_ok = core_controller(core, PANDA, o)  # the core itself checks the gains it is configured with
    assert p_ok is not None
    p = core.ControllerParams()
    p.detection_filter_gain = np.array([-1.0])
    with pytest.raises(Exception, match="detection_filter_gain"):
        core.Controller(PANDA.pin_model.saveToString(), p)


def _like(robot, o: Oracle) -> Controller:
    return controller_like(robot, o, detection_filter_gain=o.detection_filter_gain)


def _panda_log(seconds: float = 0.4, push: float = 40.0):
    """The oracle's seeded Panda run (measured signals along a random reference with noise), every tick accepted,
    with ``push`` Nm added to joint 2's measured torque from tick 100 (0.1 s) on, as an external torque shows."""
    rows = [(t, q, dq, tau) for _, (t, q, dq, tau, *_) in ticks(PANDA, push=push, faults=False,
                                                                    n_ticks=int(round(seconds / DT)))]  # fmt: skip
    t, q, dq, tau = (np.array(x) for x in zip(*rows, strict=True))
    return t, q, dq, tau


#: [s] the Controller's detection on a ramp against the cascade's continuous ramp lag: test_detection_tuning's two
#: periods (the detector checks once per tick; the observer holds the period's mean torque) and one more for the
#: stage, which filters the observer's output sampled once per tick.
CASCADE_LAG_TOLERANCE_S = 3 * DT


@pytest.mark.parametrize(("gain", "filter_gain"), [(100.0, 200.0), (200.0, 200.0), (50.0, 500.0)])
def test_controller_detects_a_ramp_at_the_cascade_s_ramp_lag(atlas, gain, filter_gain):
    """A ramp of external torque on joint 2 of the still arm (no noise): the Controller with the stage detects it
    ramp_lag(zeta, slope, 1/k_o, 1/K_f) after the torque exceeds zeta (the tuning's analytic lag, root-found on the
    cascade's continuous response), within CASCADE_LAG_TOLERANCE_S."""
    from reflexarm.experiments.collision import EE_START
    from reflexarm.signals import Measurement, Reference
    from reflexarm.tuning import ramp_lag

    slope, zeta, j, N = 400.0, 8.0, 1, 1000
    levels = np.full(atlas.n, 1e3)
    levels[j] = zeta
    ctrl = Controller(atlas, detection_observer_gain=gain, detection_filter_gain=filter_gain, threshold=levels,
                      observer_discretization="exact", reaction="none", torque_limit=None)  # fmt: skip
    g = atlas.compute_gravity(EE_START)
    zeros, gravity = np.zeros(atlas.n), np.asarray(atlas.gravity, dtype=float)
    t_detect = None
    for k in range(N):
        tau = g.copy()
        tau[j] -= slope * DT * k
        if ctrl.step(Measurement(k * DT, EE_START, zeros, tau, np.zeros(6), gravity),
                     Reference(EE_START, zeros, zeros)).collision:  # fmt: skip
            t_detect = k * DT
            break
    assert t_detect is not None
    want = ramp_lag(zeta, slope, 1.0 / gain, 1.0 / filter_gain)
    assert t_detect - zeta / slope == pytest.approx(want, abs=CASCADE_LAG_TOLERANCE_S)
    assert want > ramp_lag(zeta, slope, 1.0 / gain)


@pytest.mark.parametrize("form", ["euler", "exact"])
@pytest.mark.parametrize("band", [None, 0.1])
def test_replay_with_the_stage_is_the_refiltered_first_order_replay(atlas, form, band):
    """The tuning's shortcut: one first-order replay at 400 1/s refiltered to (40 1/s, K_f 60 1/s) equals a replay
    through the Controller with the stage (either observer form; with the detection observer's own friction model
    too), and records the stage."""
    from reflexarm.tuning import ObserverSettings, refilter, replay_residual
    from test_detection_tuning import _still_log

    log = _still_log(atlas, 2.0, seed=1)
    base = ObserverSettings(detection_observer_gain=400.0, observer_discretization="exact",
                            detection_friction_band=band)  # fmt: skip
    fast = replay_residual(log, atlas, base)
    s = ObserverSettings(detection_observer_gain=40.0, observer_discretization=form, detection_friction_band=band,
                         detection_filter_gain=60.0)  # fmt: skip
    staged = replay_residual(log, atlas, s)
    assert staged.detection_filter_gain == 60.0 and fast.detection_filter_gain is None
    # 1e-9 Nm as test_detection_tuning's refilter check: the inverse filter divides by 1 - e^{-0.4}
    np.testing.assert_allclose(refilter(fast, 40.0, form, filter_gain=60.0).residual, staged.residual, atol=1e-9)
    assert np.max(np.abs(refilter(fast, 40.0, form).residual - staged.residual)) > 1e-3  # the stage is seen
