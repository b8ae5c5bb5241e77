"""The detection residual's second stage in ``reflexarm.tuning``: r2_k = c r2_(k-1) + (1 - c) r_k, c = e^(-K_f h).

Checked without the Controller (whose ``detection_filter_gain`` keyword the compiled core may not have yet): the
residuals are built from a known input u (seeded Gaussian noise, or a step) through the recursions directly, so
:func:`refilter` is compared with the cascade computed from u, the analytic lags with a fine-step simulation of the
continuous cascade, and the (k_o, zeta) pairs are tuned on such residuals.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from reflexarm.errors import ConfigError
from reflexarm.tuning import (
    ObserverSettings,
    ResidualReplay,
    detection_delay,
    propose_detection_pairs,
    ramp_lag,
    refilter,
)
from reflexarm.tuning._report import format_pairs
from reflexarm.tuning.delays import ROOT_XTOL
from reflexarm.tuning.heldout import count_alarms

DT = 1e-3
#: Round-off of refilter against the cascade computed from u, relative to the residual's largest value: undoing a
#: stage divides by (1 - a)(1 - c) >= 0.0047 here (k_o = 40, K_f = 25 at 1 ms; 400 1/s: 0.33), so double round-off
#: (1e-16) grows to ~2e-14 at most; 1e-11 leaves a margin and still sees any wrong pole (an error of ~1e-3).
REFILTER_RTOL = 1e-11
#: The period of the fine-step simulation of the continuous cascade [s] (T >= 2 ms: >= 2000 steps per constant).
SIM_DT = 1e-6
#: Analytic crossing time against the simulation: the simulated crossing is found to a step (SIM_DT), and each
#: stage's recursion, fed its input sampled at the end of the step, is off the continuous response by up to half
#: a step (2 x SIM_DT / 2); measured: <= 1.5e-6 s on these cases.
SIM_TOL_S = 3 * SIM_DT


def _first_order(u: np.ndarray, gain: float) -> np.ndarray:
    a = math.exp(-gain * DT)
    return lfilter([1.0 - a], [1.0, -a], u, axis=0)


def _stage(r: np.ndarray, filter_gain: float) -> np.ndarray:
    c = math.exp(-filter_gain * DT)
    return lfilter([1.0 - c], [1.0, -c], r, axis=0)


def _noise(seconds: float, n: int, seed: int, sigma: float = 1.0) -> np.ndarray:
    """Seeded Gaussian input u (N, n) [Nm], 0 at the first tick (where the controller's residual is 0)."""
    u = np.random.default_rng(seed).normal(0.0, sigma, (int(round(seconds / DT)), n))
    u[0] = 0.0
    return u


def _replay(u: np.ndarray, gain: float, filter_gain: float | None = None, source: str = "noise") -> ResidualReplay:
    """The residual of an exact observer of ``gain`` on input ``u`` (then the stage ``filter_gain``), as a replay."""
    r = _first_order(u, gain)
    if filter_gain is not None:
        r = _stage(r, filter_gain)
    t = DT * np.arange(u.shape[0])
    return ResidualReplay(source, t, r, DT, 0, (), gain, "exact", filter_gain)


def _close(a: np.ndarray, b: np.ndarray, rtol: float) -> None:
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * float(np.abs(b).max()))


# --- refilter: undo the replay's stages, apply the new ones ---------------------------------------------------------


def test_refilter_adds_the_stage_to_a_first_order_replay():
    """(K, None) -> (K, K_f) is the stage's lfilter of the K residual; from another gain it is the cascade from u."""
    u = _noise(3.0, 3, seed=1)
    first = _replay(u, 100.0)
    staged = refilter(first, 100.0, filter_gain=50.0)
    _close(staged.residual, _stage(first.residual, 50.0), 1e-12)
    assert (staged.detection_gain, staged.discretization, staged.detection_filter_gain) == (100.0, "exact", 50.0)
    # from 400 1/s: the old observer undone, the new one and the stage applied
    _close(refilter(_replay(u, 400.0), 40.0, filter_gain=25.0).residual, _stage(_first_order(u, 40.0), 25.0),
           REFILTER_RTOL)  # fmt: skip
    assert np.abs(staged.residual).max() < 0.8 * np.abs(first.residual).max()  # the stage filtered something


def test_refilter_undoes_a_replay_s_stage():
    """A replay through (K, K_f) refiltered back to first order is the K replay; to (K', K_f') the cascade from u."""
    u = _noise(3.0, 3, seed=2)
    staged = _replay(u, 100.0, 50.0)
    back = refilter(staged, 100.0)
    _close(back.residual, _first_order(u, 100.0), REFILTER_RTOL)
    assert back.detection_filter_gain is None
    _close(refilter(staged, 40.0, filter_gain=25.0).residual, _stage(_first_order(u, 40.0), 25.0), REFILTER_RTOL)
    # nothing changes: the same object; the same cascade named the other way round: the same residual, relabelled
    assert refilter(staged, 100.0, filter_gain=50.0) is staged
    swapped = refilter(staged, 50.0, filter_gain=100.0)
    assert swapped.residual is staged.residual and swapped.detection_filter_gain == 100.0


def test_a_step_through_refilter_is_the_analytic_discrete_cascade():
    """u = 0 at the first tick, 1 after: the first-order replay is 1 - a^k, and refiltered to (K, K_f) it is the
    cascade's y_k = 1 - (a^(k+1) (1 - c) - c^(k+1) (1 - a)) / (a - c), from 400 1/s or from the same gain."""
    N, K, Kf = 400, 40.0, 25.0
    k = np.arange(N)
    a, c = math.exp(-K * DT), math.exp(-Kf * DT)
    expected = 1.0 - (a ** (k + 1) * (1 - c) - c ** (k + 1) * (1 - a)) / (a - c)
    for gain in (K, 400.0):
        g = math.exp(-gain * DT)
        rep = ResidualReplay("step", DT * k, (1.0 - g**k)[:, None], DT, 0, (), gain, "exact")
        np.testing.assert_allclose(refilter(rep, K, filter_gain=Kf).residual[:, 0], expected, rtol=0, atol=1e-12)


def test_refusals_of_a_bad_filter_gain():
    for bad in (0.0, -5.0, math.nan, math.inf, True, "50"):
        with pytest.raises(ConfigError, match="detection_filter_gain"):
            ObserverSettings(detection_filter_gain=bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="detection_filter_gain"):
        refilter(_replay(_noise(0.1, 1, seed=3), 100.0), 100.0, filter_gain=-1.0)
    with pytest.raises(ConfigError, match="filter_time_constant"):
        ramp_lag(1.0, 100.0, 0.01, 0.0)
    s = ObserverSettings(detection_observer_gain=100.0, detection_filter_gain=50.0)
    assert s.detection_time_scale == pytest.approx(0.01 + 0.02, rel=1e-15) and s.filter_time_constant == 0.02
    assert ObserverSettings(detection_observer_gain=100.0).detection_time_scale == 0.01
    assert s.as_dict()["detection_filter_gain"] == 50.0  # recorded with the settings (thresholds.json "observer")


# --- the cascade's continuous-time lag and delay --------------------------------------------------------------------


def _simulated(u: np.ndarray, t1: float, t2: float) -> np.ndarray:
    """The cascade's response to ``u`` sampled at SIM_DT: each stage exact for an input held over a step."""
    out = u
    for T in (t1, t2):
        a = math.exp(-SIM_DT / T)
        out = lfilter([1.0 - a], [1.0, -a], out)
    return out


CASES = [(0.01, 0.005), (0.01, 0.01), (0.002, 0.02), (0.01, 0.003)]


@pytest.mark.parametrize(("t1", "t2"), CASES)
@pytest.mark.parametrize(("zeta", "slope"), [(8.0, 400.0), (2.0, 1000.0), (5.0, 100.0)])
def test_cascade_ramp_lag_matches_a_fine_simulation(t1, t2, zeta, slope):
    t0 = zeta / slope
    t = SIM_DT * np.arange(int((t0 + 2 * (t1 + t2)) / SIM_DT))
    r = _simulated(slope * t, t1, t2)
    lag_sim = t[np.flatnonzero(r > zeta)[0]] - t0
    lag = ramp_lag(zeta, slope, t1, t2)
    assert lag == pytest.approx(lag_sim, abs=SIM_TOL_S)
    assert 0.0 < lag <= t1 + t2  # the sum of the time constants bounds any ramp's lag


@pytest.mark.parametrize(("t1", "t2"), CASES)
@pytest.mark.parametrize(("zeta", "step", "baseline"), [(1.0, 2.0, 0.0), (1.0, 1.2, 0.0), (10.0, 30.0, -2.0)])
def test_cascade_step_delay_matches_a_fine_simulation(t1, t2, zeta, step, baseline):
    t = SIM_DT * np.arange(int(15 * (t1 + t2) / SIM_DT))
    r = baseline + _simulated(np.full(t.size, step), t1, t2)
    delay = detection_delay(zeta, step, t1, baseline, filter_time_constant=t2)
    assert delay == pytest.approx(t[np.flatnonzero(r > zeta)[0]], abs=SIM_TOL_S)


def test_a_vanishing_stage_recovers_the_first_order_formulas():
    """T_f -> 0: the cascade's lag and delay tend to the closed forms (Lambert W, -T ln(1 - zeta/s)); a stage of
    T_f adds at most T_f (the slow ramp's asymptote grows by exactly T_f)."""
    T, tf = 0.01, 1e-9
    for zeta, slope in ((8.0, 400.0), (1e-3, 1e3), (100.0, 1.0)):
        assert ramp_lag(zeta, slope, T, tf) == pytest.approx(ramp_lag(zeta, slope, T), abs=tf + 4 * ROOT_XTOL * T)
    for zeta, step, b in ((1.0, 2.0, 0.0), (1.0, 1.01, 0.0), (10.0, 30.0, -2.0)):
        assert detection_delay(zeta, step, T, b, tf) == pytest.approx(-T * math.log1p(-(zeta - b) / step),
                                                                      abs=tf + 4 * ROOT_XTOL * T)  # fmt: skip
    assert detection_delay(3.0, 2.0, T, filter_time_constant=0.005) is None  # a step below zeta never crosses
    assert detection_delay(1.0, 2.0, T, 2.0, 0.005) == 0.0  # already over
    assert ramp_lag(100.0, 1.0, T, 0.005) == pytest.approx(T + 0.005, rel=1e-9)  # a slow ramp trails by T + T_f


@pytest.mark.parametrize("kind", ["ramp", "step"])
def test_equal_poles_are_continuous_with_nearby_unequal_ones(kind):
    """Across the equal-poles switch (relative 1e-9) the lag moves by no more than T_f does (|d lag / d T_f| <= 1)
    and rises with T_f: the general form has no cancellation error near T_1 = T_2 (which would be ~1e-9 s)."""
    T = 0.01

    def lag(t2: float) -> float:
        if kind == "ramp":
            return ramp_lag(8.0, 400.0, T, t2)
        d = detection_delay(1.0, 2.0, T, filter_time_constant=t2)
        assert d is not None
        return d

    rels = (-1e-7, -1e-8, -2e-9, -5e-10, 0.0, 5e-10, 2e-9, 1e-8, 1e-7)
    lags = [lag(T * (1.0 + r)) for r in rels]
    at_equal = lags[rels.index(0.0)]
    for r, x in zip(rels, lags, strict=True):
        assert abs(x - at_equal) <= abs(r) * T + 4 * ROOT_XTOL * 2 * T
    assert all(b > a for a, b in zip(lags, lags[1:], strict=False))


# --- (k_o, zeta) pairs with the stage --------------------------------------------------------------------------------

GAINS = (20.0, 100.0)
KF = 50.0
#: The reference replays' gain: the pairs refilter them to each gain (and stage).
K_REF = 400.0


@pytest.fixture(scope="module")
def noise_pairs(atlas):
    """Pairs tuned on first-order replays of Gaussian noise at K_REF (2 x 60 s), held out on a third seed, with
    and without the stage."""
    tune = [_replay(_noise(60.0, atlas.n, seed=s), K_REF, source=f"noise {s}") for s in (31, 32)]
    held_u = _noise(30.0, atlas.n, seed=33)
    held = [_replay(held_u, K_REF, source="noise 33")]
    kw = dict(heldout=held, rate_per_hour=60.0, contact_rate_per_hour=600.0, lag_draws=30, seed=0)
    staged = propose_detection_pairs(tune, atlas, GAINS, settings=ObserverSettings(detection_filter_gain=KF), **kw)
    plain = propose_detection_pairs(tune, atlas, GAINS, **kw)
    return staged, plain, held_u


def test_the_stage_lowers_the_levels_and_is_recorded(noise_pairs):
    staged, plain, _ = noise_pairs
    for s, p in zip(staged.pairs, plain.pairs, strict=True):
        assert s.gain == p.gain
        assert np.all(s.collision < 0.9 * p.collision)  # the stage filtered the noise
        assert s.detection_filter_gain == KF and p.detection_filter_gain is None
        # the tail fit's default gap: 5 x (1/k_o + 1/K_f)
        assert all(j.fit.gap_s == pytest.approx(5.0 * (1.0 / s.gain + 1.0 / KF), rel=1e-12) for j in s.proposal.joints)
    d = staged.as_dict()
    assert d["detection_filter_gain"] == KF and plain.as_dict()["detection_filter_gain"] is None
    assert all(x["detection_filter_gain"] == KF for x in d["pairs"])
    assert all(row["detection_filter_gain"] == KF for row in staged.rows())
    assert f"second stage K_f = {KF:g} 1/s" in format_pairs(staged) and "second stage" not in format_pairs(plain)


def test_each_pair_s_proposal_reports_the_cascade_s_delays(noise_pairs):
    """tune_thresholds at (k_o, K_f): the settings carry K_f (thresholds.json's "observer"), the delay of the step
    torque solves zeta = s (1 - (T1 e^(-t/T1) - T2 e^(-t/T2)) / (T1 - T2)) (written out here), and the report
    names the stage."""
    from reflexarm.tuning._report import format_report

    staged, _, _ = noise_pairs
    for pair in staged.pairs:
        prop, T1, T2 = pair.proposal, 1.0 / pair.gain, 1.0 / KF
        d = prop.as_dict()
        assert d["observer"]["detection_filter_gain"] == KF and d["filter_time_constant_s"] == pytest.approx(T2)
        for jt in prop.joints:
            t = jt.delays["collision_delay_s"]
            assert t is not None
            rise = 1.0 - (T1 * math.exp(-t / T1) - T2 * math.exp(-t / T2)) / (T1 - T2)
            assert prop.step_torque * rise == pytest.approx(jt.collision, rel=1e-9)
        assert f"second stage K_f = {KF:g} 1/s" in format_report(prop)


def test_the_pairs_lags_are_the_cascade_s(noise_pairs):
    """The analytic step lag solves 1 - (T1 e^(-t/T1) - T2 e^(-t/T2)) / (T1 - T2) = 1/s (written out here); the
    ramp lags exceed the first order's and stay below 1/k_o + 1/K_f; the measured step lags (the synthetic step
    through both stages, on noise) are longer than without the stage."""
    staged, plain, _ = noise_pairs
    for s, p in zip(staged.pairs, plain.pairs, strict=True):
        T1, T2, t = 1.0 / s.gain, 1.0 / KF, s.step_lag_s
        assert 1.0 - (T1 * math.exp(-t / T1) - T2 * math.exp(-t / T2)) / (T1 - T2) == pytest.approx(
            1.0 / staged.step_size, rel=1e-9
        )
        assert p.step_lag_s == pytest.approx(T1 * math.log(2.0), rel=1e-12)
        assert all(a > b for a, b in zip(s.ramp_lag_s, [ramp_lag(z, staged.ramp_slope, T1) for z in s.collision],
                                         strict=True))  # fmt: skip
        assert max(s.ramp_lag_s) < T1 + T2
        assert np.nanmedian(s.measured_step_lag_s) > np.nanmedian(p.measured_step_lag_s)


def test_the_held_out_alarms_decluster_with_the_cascade_s_gap(atlas, noise_pairs):
    """The held-out alarms are those of the cascade's residual (computed here from u) at the pair's levels, and two
    excursions 5/k_o < apart < 5 (1/k_o + 1/K_f) are one alarm: pulses 120 ms apart at k_o = 100, K_f = 50 (the
    excursions last ~35 ms, so ~85 ms lie between them: more than the first order's 50 ms, less than 150 ms)."""
    staged, _, held_u = noise_pairs
    for s in staged.pairs:
        gap = 5.0 * (1.0 / s.gain + 1.0 / KF)
        assert s.heldout is not None and s.heldout["gap_s"] == pytest.approx(gap, rel=1e-12)
        r = _stage(_first_order(held_u, s.gain), KF)
        assert s.heldout["alarms"] == count_alarms(r, s.collision, DT, gap)["alarms"]
        assert s.heldout["duration_s"] == pytest.approx(30.0, rel=1e-9)
    u = np.zeros((2000, atlas.n))
    u[[500, 620]] = 100.0  # two one-tick pulses [Nm] on every joint
    tune = [_replay(_noise(60.0, atlas.n, seed=s), K_REF, source=f"noise {s}") for s in (31, 32)]
    pair = propose_detection_pairs(tune, atlas, (100.0,), heldout=[_replay(u, K_REF, source="pulses")],
                                   settings=ObserverSettings(detection_filter_gain=KF), rate_per_hour=60.0,
                                   contact_rate_per_hour=600.0, lag_draws=5).pairs[0]  # fmt: skip
    r = _stage(_first_order(u, 100.0), KF)
    assert np.all(np.abs(r).max(axis=0) > 2.0 * pair.collision)  # each pulse crosses every level
    assert count_alarms(r, pair.collision, DT, 5.0 / 100.0)["alarms"] == 2  # the first order's gap: two alarms
    assert pair.heldout is not None and pair.heldout["alarms"] == 1
