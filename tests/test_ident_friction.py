"""Single-joint friction identification: planner, segmentation, fit; recovery on the simulated plant."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError, IdentificationError
from reflexarm.ident import (
    FrictionPoint,
    fit_friction,
    plan_friction_experiment,
    segment_constant_velocity,
)
from reflexarm.robots import perturb_model


def _points(mu, dv, offset=0.0, speeds=(0.1, 0.3, 0.6, 1.0)):
    pts = []
    for v in speeds:
        for s in (1, -1):
            pts.append(FrictionPoint(2, s * v, dv * s * v + mu * s + offset, 0.0, 100, 0.0, 1.0))
    return pts


def test_fit_recovers_coulomb_viscous_and_offset_from_exact_points():
    fit = fit_friction(_points(10.3, 1.6))
    assert fit.coulomb == pytest.approx(10.3) and fit.viscous == pytest.approx(1.6) and fit.offset is None
    fit = fit_friction(_points(10.3, 1.6, offset=-0.7), offset=True)
    assert (fit.coulomb, fit.viscous, fit.offset) == pytest.approx((10.3, 1.6, -0.7))
    assert fit.rms_residual < 1e-12


def test_fit_refuses_underdetermined_problems():
    with pytest.raises(IdentificationError, match=r"2 friction points cannot determine 3 parameters"):
        fit_friction(_points(1.0, 1.0, speeds=(0.5,)), offset=True)
    one_way = [p for p in _points(1.0, 1.0) if p.velocity > 0]
    with pytest.raises(IdentificationError, match=r"Coulomb friction and an offset need points in both directions"):
        fit_friction(one_way, offset=True)


def test_planner_stays_within_limits_and_runs_each_speed_both_ways(atlas):
    plan = plan_friction_experiment(atlas, 2, speeds=(0.2, 0.5, 20.0))  # 20 rad/s is above the limit
    w = plan.windows
    np.testing.assert_allclose(sorted(np.abs(w[:, 2])), [0.2, 0.2, 0.5, 0.5])
    assert set(np.sign(w[:, 2])) == {-1.0, 1.0}
    t = np.arange(0.0, plan.duration, 1e-3)
    q, dq, ddq = plan.evaluate(t)
    assert np.all(q[:, 2] >= atlas.lower_limit[2] + 0.15 - 1e-12) and np.all(q[:, 2] <= atlas.upper_limit[2] - 0.15)
    np.testing.assert_array_equal(q[:, [0, 1, 3, 4, 5, 6]], np.broadcast_to(plan.hold[[0, 1, 3, 4, 5, 6]], (t.size, 6)))
    for t0, t1, v in w:  # constant commanded speed inside each window
        inside = (t > t0 + 1e-9) & (t < t1 - 1e-9)
        np.testing.assert_allclose(dq[inside, 2], v)
    for k in (0, 1234, 5678, t.size - 1):  # the runner's scalar path agrees with the vectorised one
        ref = plan.sample(t[k])
        np.testing.assert_allclose(np.r_[ref.q_d, ref.dq_d, ref.ddq_d], np.r_[q[k], dq[k], ddq[k]], atol=1e-12)
    lo, hi = plan.position_window(0.3)
    assert lo < hi
    with pytest.raises(ConfigError, match=r"no usable speed for joint 3 \(l_arm_ely\)"):
        plan_friction_experiment(atlas, 2, speeds=(50.0,))
    with pytest.raises(ConfigError, match=r"joint must be an index 0\.\.6; got 7"):
        plan_friction_experiment(atlas, 7)


def test_segmentation_from_data_finds_the_planned_intervals(atlas):
    plan = plan_friction_experiment(atlas, 3, speeds=(0.2, 0.5, 1.0))
    t = np.arange(0.0, plan.duration, 1e-3)
    _, dq, _ = plan.evaluate(t)
    noisy = dq[:, 3] + np.random.default_rng(0).uniform(-0.055, 0.055, t.size)  # paper velocity noise
    found = segment_constant_velocity(t, noisy, settle=0.1)
    assert len(found) == len(plan.windows)
    for sl, (t0, t1, v) in zip(found, plan.windows, strict=True):
        assert t0 <= t[sl.start] and t[sl.stop - 1] <= t1 + 0.05
        assert np.mean(noisy[sl]) == pytest.approx(v, abs=0.01)


@pytest.mark.slow
def test_friction_from_simulated_runs_matches_table1_within_5_percent(atlas):
    """Constant-velocity runs on the MuJoCo plant with the impedance controller and the paper's noise;
    the rigid-body torque is removed with a +-10 % perturbed model (what a user has), whose mean error
    over the common position window is absorbed by the fitted offset."""
    from reflexarm.experiments.identification import HYDRAULIC_JOINTS, run_friction_experiments

    exp = run_friction_experiments(
        atlas, joints=HYDRAULIC_JOINTS, speeds=(0.25, 0.5, 1.0), travel=1.2, model=perturb_model(atlas, 0.1, seed=0)
    )
    for f in exp.fits:
        mu, dv = atlas.friction.coulomb[f.joint], atlas.friction.viscous[f.joint]
        assert f.coulomb == pytest.approx(mu, rel=0.05), f"joint {f.joint + 1}: mu_C {f.coulomb:.3f} vs {mu}"
        assert f.viscous == pytest.approx(dv, rel=0.05), f"joint {f.joint + 1}: d_v {f.viscous:.3f} vs {dv}"
        assert len(f.points) == 6
