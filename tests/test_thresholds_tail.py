"""The tail fit of reflexarm.tuning recovers levels known analytically (exponential, Gaussian, uniform tails),
counts an excursion once, and says what it did not fit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from reflexarm.errors import ConfigError, DataError
from reflexarm.tuning import cluster_maxima, fit_tail
from reflexarm.tuning.heldout import count_alarms

#: i.i.d. samples one second apart (dt = 1 s): an upcrossing rate per hour is then 3600 P(X > z) (1 - P(X > z)),
#: the rate of clusters with gap 0, so the level of a rate is known in closed form.
DT = 1.0
N = 400_000  # 111 h of samples: the rates below have return periods of 1-10 h, inside the data's span


def _exceedance_probability(rate_per_hour: float) -> float:
    """P(X > z) whose upcrossing rate p (1 - p) / DT is ``rate_per_hour``."""
    c = rate_per_hour * DT / 3600.0
    return (1.0 - math.sqrt(1.0 - 4.0 * c)) / 2.0


#: Relative tolerance of a recovered level: the fit uses the top 30 clusters (TAIL_CLUSTERS), whose PWM
#: scale has a standard error of ~20 %; levels within a few scales of u then move by ~3 %; 5 % allows for it.
LEVEL_RTOL = 0.05


@pytest.mark.parametrize("rate", [1.0, 0.2, 0.1])
def test_exponential_tail_level_is_recovered(rate):
    rng = np.random.default_rng(1)
    scale = 2.0
    x = rng.exponential(scale, N)
    fit = fit_tail(x, DT, gap_s=0.0)
    truth = -scale * math.log(_exceedance_probability(rate))
    level = fit.level(rate)
    np.testing.assert_allclose(level, truth, rtol=LEVEL_RTOL, err_msg="GPD level of an exponential tail")
    lo, hi = fit.level_interval(rate)
    assert lo <= truth <= hi, f"the 90 % interval [{lo:.3f}, {hi:.3f}] misses the true level {truth:.3f}"
    # the shape from 400 clusters (standard error ~0.05): 0 for an exponential tail
    wide = fit_tail(x, DT, gap_s=0.0, tail_clusters=400)
    assert abs(wide.xi) < 0.1, f"an exponential tail has shape 0; fitted {wide.xi:.3f}"
    # the rate at the level is the asked one (the two functions are inverse to each other)
    np.testing.assert_allclose(fit.rate(level), rate, rtol=1e-9)


@pytest.mark.parametrize("rate", [1.0, 0.2])
def test_gaussian_tail_level_is_recovered(rate):
    rng = np.random.default_rng(2)
    sigma = 0.5
    x = np.abs(rng.normal(0.0, sigma, N))
    fit = fit_tail(x, DT, gap_s=0.0)
    truth = sigma * norm.isf(_exceedance_probability(rate) / 2.0)  # |X| > z on both sides
    np.testing.assert_allclose(fit.level(rate), truth, rtol=LEVEL_RTOL, err_msg="GPD level of a Gaussian tail")


def test_bounded_tail_gives_level_below_its_end_and_the_exponential_method_is_conservative():
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 1.0, N)  # P(X > z) = 1 - z: a tail ending at 1
    rate = 0.02  # a return period of 50 h: beyond the top 30 clusters (0.27/h), inside the 111 h of data
    gpd = fit_tail(x, DT, gap_s=0.0)
    expo = fit_tail(x, DT, gap_s=0.0, method="exponential")
    assert gpd.xi < -0.3, f"a uniform tail has shape -1; fitted {gpd.xi:.3f}"
    assert gpd.u < gpd.level(rate) <= 1.0, "the level of a bounded tail lies between u and the tail's end"
    assert expo.level(rate) > 1.0, "xi = 0 extrapolates a bounded tail beyond its end (conservative)"


def test_an_excursion_is_counted_once_however_long():
    rng = np.random.default_rng(4)
    # 12 plateaus of 2 s at 1 kHz with noise; between them 0.5 s near zero
    dt = 1e-3
    one = np.r_[np.full(2000, 10.0), np.zeros(500)]
    x = np.tile(one, 12) + rng.uniform(-0.05, 0.05, 12 * one.size)
    assert cluster_maxima(x, 9.0, gap=int(0.3 / dt)).size == 12
    # with a gap longer than the pauses the plateaus merge into one excursion
    assert cluster_maxima(x, 9.0, gap=int(1.0 / dt)).size == 1
    # the noise crosses 10.0 many times within a plateau: each crossing is its own run when gap = 0
    assert cluster_maxima(x, 10.0, gap=0).size > 12 * 10


def test_levels_above_the_fit_threshold_rate_are_counted_not_fitted():
    rng = np.random.default_rng(5)
    x = rng.exponential(1.0, N)
    fit = fit_tail(x, DT, gap_s=0.0)
    rate = 10 * fit.rate_u  # below u: the counted cluster rate
    level = fit.level(rate)
    assert level < fit.u
    counted = cluster_maxima(x, level, 0).size / fit.duration_h
    np.testing.assert_allclose(counted, rate, rtol=0.05, err_msg="counted rate at the interpolated level")


def test_a_log_without_enough_excursions_is_refused_with_the_counts():
    x = np.r_[np.zeros(1000), np.linspace(4.0, 5.0, 1000), np.zeros(1000)]  # one excursion
    with pytest.raises(DataError, match=r"need 20 clusters above the fit threshold; found 1 above the 99.9 %, "):
        fit_tail(x, 1e-3, gap_s=0.1)
    with pytest.raises(ConfigError, match="unknown tail method 'weibull'; choose one of: gpd, exponential"):
        fit_tail(x, 1e-3, gap_s=0.1, method="weibull")
    fit = fit_tail(np.random.default_rng(0).exponential(1.0, 10_000), 1.0, gap_s=0.0)
    with pytest.raises(ConfigError, match="a false-alarm rate must be positive"):
        fit.level(0.0)


def test_count_alarms_merges_joints_and_close_excursions():
    dt = 1e-3
    r = np.zeros((10_000, 2))
    r[1000:1100, 0] = 5.0  # joint 1 at 1 s
    r[1050:1200, 1] = -5.0  # joint 2 overlapping: the same alarm of the arm
    r[1300:1400, 0] = 5.0  # 0.1 s later: the same alarm with a 0.5 s gap
    r[8000:8100, 1] = 5.0  # a separate alarm
    res = count_alarms(r, [4.0, 4.0], dt, gap_s=0.5)
    assert res["alarms"] == 2
    assert res["alarms_per_joint"] == {"1": 1, "2": 2}
    np.testing.assert_allclose(res["alarm_times_s"], [1.0, 8.0], atol=dt)
    assert count_alarms(r, [6.0, 6.0], dt, gap_s=0.5)["alarms"] == 0


def test_the_lowest_level_the_logs_cross_at_most_k_times():
    from reflexarm.tuning._log_check import count_crossings, lowest_level_crossed_at_most

    dt = 1e-3
    x = np.zeros(20_000)
    for k in range(10):  # separate excursions of heights 1..10, 2 s apart
        x[k * 2000 + 500 : k * 2000 + 600] = k + 1.0
    fit = fit_tail(np.r_[x, np.random.default_rng(0).exponential(0.1, 200_000)], dt, gap_s=0.1)
    assert count_crossings([x], 6.5, dt, fit)[0] == 4  # 7, 8, 9, 10
    level = lowest_level_crossed_at_most([x], 2.0, dt, fit, allowed=3)
    # heights 8, 9, 10 may stay above it: the level lies in [7, 8); the grid's step is 0.5 % of (10 - 2)
    assert 7.0 <= level < 7.0 + 0.005 * 8.0 + 1e-9
    assert count_crossings([x], level, dt, fit)[0] == 3
