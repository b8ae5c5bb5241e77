"""(k_o, zeta) pairs of ``reflexarm.tuning``: the refiltered residual is the controller's own at that gain, the
ramp lag formula is the exact observer's, the pairs trade lag for level, and a file of pairs drives the
Controller at the gain it was tuned for."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from reflexarm._cli.common import read_threshold
from reflexarm.control import Controller
from reflexarm.experiments.collision import EE_START
from reflexarm.logs.robot_log import RobotLog
from reflexarm.signals import Measurement, Reference
from reflexarm.tuning import (
    ObserverSettings,
    propose_detection_pairs,
    ramp_lag,
    refilter,
    replay_residual,
    tune_thresholds,
)
from reflexarm.tuning.output import write_thresholds

DT = 1e-3
#: Velocity noise of the paper (uniform, +-) [rad/s].
DQ_NOISE = 5.5e-2
#: The exact observer's ramp lag against the continuous formula: one period for the detector checking once per
#: tick, one for the observer holding the tick's sampled torque over the period (zero-order hold).
LAG_TOLERANCE_S = 2 * DT


def _still_log(robot, seconds: float, seed: int, tau_ext: np.ndarray | None = None) -> RobotLog:
    """The arm held still at EE_START, its velocity measured with the paper's uniform noise; the motor torque is
    g(q) - tau_ext (eq. (1) at rest). The residual then carries only the velocity noise through M(q)."""
    rng = np.random.default_rng(seed)
    N = int(round(seconds / DT))
    q = np.tile(EE_START, (N, 1))
    ext = np.zeros((N, robot.n)) if tau_ext is None else tau_ext
    tau = robot.compute_gravity(EE_START)[None, :] - ext
    dq = rng.uniform(-DQ_NOISE, DQ_NOISE, (N, robot.n))
    return RobotLog(t=np.arange(N) * DT, q=q, dq=dq, tau=tau, source=f"still, noise seed {seed}")


@pytest.mark.parametrize("form", ["exact", "euler"])
def test_refiltered_residual_is_the_controllers_at_that_gain(atlas, form):
    """One replay at 400 1/s refiltered to 40 1/s equals a replay through the Controller at 40 1/s."""
    log = _still_log(atlas, 2.0, seed=1)
    fast = replay_residual(log, atlas, ObserverSettings(detection_observer_gain=400.0, observer_discretization="exact"))
    slow = replay_residual(log, atlas, ObserverSettings(detection_observer_gain=40.0, observer_discretization=form))
    # 1e-9 Nm: the inverse filter divides by 1 - e^{-0.4}; round-off of residuals of ~10 Nm stays far below
    np.testing.assert_allclose(refilter(fast, 40.0, form).residual, slow.residual, atol=1e-9)


@pytest.mark.parametrize("gain", [20.0, 100.0, 500.0])
def test_exact_observer_lags_a_ramp_as_the_first_order_formula(atlas, gain):
    """A ramp of external torque on joint 2 of the still arm (no noise): the Controller (exact form) detects it
    ramp_lag(zeta, slope, 1/k_o) after the torque exceeds zeta, within LAG_TOLERANCE_S."""
    slope, zeta, j = 400.0, 8.0, 1
    N = 1000
    ext = np.zeros((N, atlas.n))
    ext[:, j] = slope * DT * np.arange(N)
    levels = np.full(atlas.n, 1e3)
    levels[j] = zeta
    ctrl = Controller(atlas, detection_observer_gain=gain, observer_discretization="exact", threshold=levels,
                      reaction="none", torque_limit=None)  # fmt: skip
    g = atlas.compute_gravity(EE_START)
    zeros, gravity = np.zeros(atlas.n), np.asarray(atlas.gravity, dtype=float)
    t_detect = None
    for k in range(N):
        cmd = ctrl.step(Measurement(k * DT, EE_START, zeros, g - ext[k], np.zeros(6), gravity),
                        Reference(EE_START, zeros, zeros))  # fmt: skip
        if cmd.collision:
            t_detect = k * DT
            break
    assert t_detect is not None
    lag = t_detect - zeta / slope
    assert lag == pytest.approx(ramp_lag(zeta, slope, 1.0 / gain), abs=LAG_TOLERANCE_S)


def test_ramp_lag_tends_to_the_time_constant_and_to_zero():
    T = 0.01
    assert ramp_lag(100.0, 1.0, T) == pytest.approx(T, rel=1e-9)  # a slow ramp trails by T
    assert ramp_lag(1e-4, 1e3, T) < 0.1 * T  # a steep one is detected almost at once
    lags = [ramp_lag(10.0, s, T) for s in (1e2, 1e3, 1e4, 1e5)]
    assert lags == sorted(lags, reverse=True)


@pytest.fixture(scope="module")
def pairs(atlas):
    logs = [_still_log(atlas, 40.0, seed=s) for s in (11, 12)]
    held = [_still_log(atlas, 20.0, seed=13)]
    return propose_detection_pairs(logs, atlas, (20.0, 100.0, 400.0), heldout=held, rate_per_hour=60.0,
                                   contact_rate_per_hour=600.0, lag_draws=20, seed=0)  # fmt: skip


def test_levels_rise_and_lags_fall_with_the_gain(pairs):
    """More gain passes more velocity noise (k_o M(q) sigma_dq): higher levels; and a shorter lag."""
    p = pairs.pairs
    assert [x.gain for x in p] == [20.0, 100.0, 400.0]
    for a, b in zip(p, p[1:], strict=False):
        assert np.all(b.collision > a.collision)
        assert max(b.ramp_lag_s) < max(a.ramp_lag_s) and b.step_lag_s < a.step_lag_s
        assert np.nanmedian(b.measured_step_lag_s) < np.nanmedian(a.measured_step_lag_s)
    # the noise's growth: the shoulder's level at 400 1/s is several times the one at 20 1/s
    assert p[2].collision[0] > 3.0 * p[0].collision[0]
    d = pairs.as_dict()["pairs"][1]
    assert d["detection_observer_gain"] == 100.0 and d["observer_discretization"] == "exact"
    assert d["heldout"]["duration_s"] == pytest.approx(20.0, rel=1e-3)


def test_a_file_of_pairs_drives_the_controller_at_its_gain(atlas, pairs, tmp_path):
    logs = [_still_log(atlas, 40.0, seed=s) for s in (11, 12)]
    proposal = tune_thresholds(logs, atlas, rate_per_hour=60.0, contact_rate_per_hour=600.0)
    proposal.detection_pairs = pairs.as_dict()
    path = write_thresholds(proposal, tmp_path, figure=False)["json"]
    assert "detection_pairs" in json.loads(path.read_text())
    zeta, source, tuned = read_threshold(str(path), atlas, 100.0)
    np.testing.assert_allclose(zeta, pairs.pair(100.0).collision, rtol=1e-12)
    assert tuned == 100.0 and "100" in source
    # a gain without a pair: the file's own levels, tuned for its own gain (the CLI warns on the mismatch)
    top, _, top_gain = read_threshold(str(path), atlas, 70.0)
    np.testing.assert_allclose(top, proposal.collision, rtol=1e-12)
    assert top_gain == 5.0
    # the pair drives the controller: a step of 3 zeta on joint 1 is detected there; the noise alone is not
    j, k0 = 0, 500
    ext = np.zeros((1000, atlas.n))
    ext[k0:, j] = 3.0 * zeta[j]
    log = _still_log(atlas, 1.0, seed=21, tau_ext=ext)
    ctrl = Controller(atlas, detection_observer_gain=tuned, observer_discretization="exact", threshold=zeta,
                      reaction="none", torque_limit=None)  # fmt: skip
    gravity = np.asarray(atlas.gravity, dtype=float)
    flags = []
    for k in range(log.t.size):
        cmd = ctrl.step(Measurement(log.t[k], log.q[k], log.dq[k], log.tau[k], np.zeros(6), gravity),
                        Reference(log.q[k], np.zeros(atlas.n), np.zeros(atlas.n)))  # fmt: skip
        flags.append((cmd.collision, tuple(cmd.collided_joints)))
    first = next(k for k, (c, _) in enumerate(flags) if c)
    assert first >= k0
    assert j in flags[first][1]
    assert first - k0 <= math.ceil(math.log(1.5) * 1.0 / tuned / DT) + 2  # T ln(3/2) plus two ticks


def test_the_detection_observer_s_own_friction_refilters_and_is_named_in_the_pairs(atlas):
    """With the detection observer's own friction model (0.1 rad/s band), one replay refiltered to another gain still
    equals the Controller at that gain (the friction is in the input u, which does not depend on the gain); the
    pairs tuned with it say so in their JSON and in the printed table."""
    from reflexarm.tuning._report import format_pairs

    log = _still_log(atlas, 2.0, seed=1)
    def at(gain: float, band: float | None = 0.1):
        settings = ObserverSettings(detection_observer_gain=gain, observer_discretization="exact",
                                    detection_friction_band=band)  # fmt: skip
        return replay_residual(log, atlas, settings)

    fast, slow, without = at(400.0), at(40.0), at(40.0, None)
    np.testing.assert_allclose(refilter(fast, 40.0).residual, slow.residual, atol=1e-9)
    assert np.abs(slow.residual - without.residual).max() > 0.1  # the band changed the residual: the test sees it
    logs = [_still_log(atlas, 20.0, seed=s) for s in (11, 12)]
    pairs = propose_detection_pairs(logs, atlas, (100.0,), rate_per_hour=600.0, contact_rate_per_hour=6000.0,
                                    allow_extrapolation=True, lag_draws=5,
                                    settings=ObserverSettings(detection_friction_band=0.1))  # fmt: skip
    assert pairs.as_dict()["detection_friction_band"] == 0.1
    assert "its friction model in a 0.1 rad/s band" in format_pairs(pairs)
