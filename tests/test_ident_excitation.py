"""Fourier excitation: rest at both ends, limits on the sampled trajectory, lower condition number."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.ident import FourierTrajectory, compute_base_parameters, optimize_excitation
from reflexarm.ident.excitation.design import regressor_condition
from reflexarm.robots import load_robot


@pytest.fixture(scope="module")
def design(atlas):
    base = compute_base_parameters(atlas)
    return optimize_excitation(
        atlas, base=base, n_harmonics=4, n_grid=100, n_samples=60, maxiter=15, seed=3, max_acceleration=4.0
    )


#: The optimizer must lower the condition number at least this much in 15 iterations. Its path is
#: machine-specific (SLSQP over a BLAS-evaluated cost): the ratio came out 0.125-0.165 under
#: OPENBLAS_CORETYPE=Haswell, Zen, SkylakeX, Sandybridge, Nehalem, Prescott and with 1 or 2 threads,
#: so 0.2 would sit within 20 % of a measured value; 0.4 still asks for a 2.5x reduction.
CONDITION_RATIO = 0.4


@pytest.mark.slow  # uses the optimized design (~30 s fixture)
def test_optimization_lowers_the_condition_number(design, atlas):
    assert design.condition_optimized < CONDITION_RATIO * design.condition_initial
    # the reported numbers are what an independent evaluation of the same regressor gives
    assert regressor_condition(atlas, design.trajectory, n_samples=60) == pytest.approx(design.condition_optimized)
    assert regressor_condition(atlas, design.initial, n_samples=60) == pytest.approx(design.condition_initial)


def test_seeded_optimization_is_repeatable_on_one_machine(atlas):
    """The same call gives the same trajectory bit for bit (same process, BLAS threads and CPU; across
    CPUs or thread counts the path differs, which is why the identification tests use fixed data)."""
    base = compute_base_parameters(atlas)
    kw = dict(base=base, n_harmonics=3, n_grid=60, n_samples=40, maxiter=5, seed=11)
    first, second = optimize_excitation(atlas, **kw), optimize_excitation(atlas, **kw)
    np.testing.assert_array_equal(first.trajectory.a, second.trajectory.a)
    np.testing.assert_array_equal(first.trajectory.b, second.trajectory.b)
    np.testing.assert_array_equal(first.trajectory.offset, second.trajectory.offset)
    assert first.condition_optimized == second.condition_optimized


@pytest.mark.slow  # uses the optimized design (~30 s fixture)
def test_optimized_trajectory_respects_the_limits_when_sampled_at_1khz(design, atlas):
    tr = design.trajectory
    t = np.arange(0.0, tr.period, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    b = design.bounds
    lo, hi = np.asarray(b["lower"]), np.asarray(b["upper"])
    # bounds include the 0.1 rad margin inside the joint limits
    np.testing.assert_array_less(atlas.lower_limit + 0.1 - 1e-9, lo + 1e-12)
    assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)
    assert np.all(np.abs(dq) <= np.asarray(b["max_velocity"]) + 1e-9)
    assert np.all(np.abs(ddq) <= 4.0 + 1e-9)
    assert max(design.limits_optimized.values()) <= 1.0
    # within by construction: the iterate was restored onto the limits at its 1 kHz peaks, and the final
    # check had nothing left to scale down
    assert design.amplitude_scale == 1.0


@pytest.mark.slow  # uses the optimized design (~30 s fixture)
def test_trajectory_starts_and_ends_at_rest_in_the_same_pose(design):
    tr = design.trajectory.with_periods(2)
    q, dq, ddq = tr.evaluate(np.array([0.0, tr.period, tr.duration]))
    np.testing.assert_allclose(dq, 0.0, atol=1e-12)
    np.testing.assert_allclose(ddq, 0.0, atol=1e-12)
    np.testing.assert_allclose(q[0], q[2], atol=1e-12)
    np.testing.assert_allclose(q[0], tr.start, atol=1e-12)
    # outside [0, duration] the trajectory holds its start pose
    ref = tr.sample(tr.duration + 1.0)
    np.testing.assert_allclose(ref.q_d, tr.start)
    np.testing.assert_array_equal(ref.dq_d, 0.0)


def test_sample_matches_evaluate_and_derivatives_are_consistent():
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.2, rng.normal(size=(3, 4)), rng.normal(size=(3, 4)), np.zeros(3))
    t = np.linspace(0.0, tr.period, 2001)
    q, dq, ddq = tr.evaluate(t)
    for k in (0, 17, 999, 2000):
        ref = tr.sample(t[k])
        np.testing.assert_allclose(ref.q_d, q[k], atol=1e-12)
        np.testing.assert_allclose(ref.dq_d, dq[k], atol=1e-12)
        np.testing.assert_allclose(ref.ddq_d, ddq[k], atol=1e-12)
    # central differences of q and dq (step 2.5 ms): O(h^2) truncation, ~1e-4 of the amplitude
    h = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(q, h, axis=0)[1:-1], dq[1:-1], atol=1e-3 * np.abs(dq).max())
    np.testing.assert_allclose(np.gradient(dq, h, axis=0)[1:-1], ddq[1:-1], atol=1e-3 * np.abs(ddq).max())


@pytest.mark.slow  # uses the optimized design (~30 s fixture)
def test_trajectory_roundtrips_through_json(design, tmp_path):
    p = design.trajectory.save(tmp_path / "exc.json")
    back = FourierTrajectory.load(p)
    np.testing.assert_array_equal(back.a, design.trajectory.a)
    # stored in Hz: w_f -> w_f / (2 pi) -> 2 pi f_f is exact to an ulp or two
    assert back.base_frequency == pytest.approx(design.trajectory.base_frequency, rel=1e-15)


def test_bad_settings_are_rejected():
    robot = load_robot("panda")
    with pytest.raises(ConfigError, match=r"n_harmonics must be >= 2 \(one is used up by the rest conditions\); got 1"):
        optimize_excitation(robot, n_harmonics=1)
    with pytest.raises(ConfigError, match=r"position_margin 2\.0 rad leaves no range on joint 2"):
        optimize_excitation(robot, position_margin=2.0)
    with pytest.raises(ConfigError, match=r"velocity and acceleration bounds must be positive"):
        optimize_excitation(robot, max_acceleration=-1.0)


@pytest.mark.slow  # a 2-iteration optimization with the torque, floor and self-collision bounds
def test_a_stalled_optimization_says_why(tmp_path):
    """With the 45 base parameters that today's tolerance gave for a 3.1416 roll (two combinations whose
    torques are 3e-6 of the largest), no motion can condition the regressor: the run ends above
    STALLED_CONDITION and says which combinations the motion cannot excite (link 1's first moments)."""
    import warnings

    from gen3_like import GEN3_TIP, write_gen3_like_urdf
    from reflexarm.ident.excitation.design import STALLED_CONDITION, ExcitationStalledWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(write_gen3_like_urdf(tmp_path, rounded_pi=True), tip=GEN3_TIP)
        base = compute_base_parameters(robot, rank_tolerance=1e-12)  # count the near-dependent ones
    assert base.n_base == 45
    with pytest.warns(ExcitationStalledWarning, match=r"cannot excite the weakest direction") as rec:
        design = optimize_excitation(
            robot, base=base, n_harmonics=3, maxiter=2, n_samples=40, n_grid=60, n_grid_dynamics=20, seed=0
        )
    w = rec[0].message
    assert isinstance(w, ExcitationStalledWarning) and w.condition == design.condition_optimized > STALLED_CONDITION
    assert any("_joint_1" in name.split()[0] for name in w.weakest), w.weakest
    assert design.diagnosis == str(w)


#: The issue's criterion: with a 3.1416 roll the excitation reaches the condition number of exact pi
#: within 5 %. Measured (this test's settings, 3 iterations): exact pi 929.16 -> 61.881, 3.1416 929.18 ->
#: 61.877 (6e-5 apart: the regressors differ by the 7.3e-6 rad tilt, same base columns; 62.023 and 62.019
#: when the final check shrank the iterate instead of restoring it); with the old tolerance's 45 base
#: parameters the rounded arm went 3.1e6 -> 4.2e5.
SAME_CONDITION = 0.05


@pytest.mark.slow  # two 3-iteration optimizations with the nonlinear bounds
def test_a_rounded_pi_reaches_the_condition_number_of_exact_pi(tmp_path):
    import warnings

    from gen3_like import GEN3_TIP, write_gen3_like_urdf

    conds = []
    for rounded in (False, True):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            robot = load_robot(write_gen3_like_urdf(tmp_path, rounded_pi=rounded), tip=GEN3_TIP)
            design = optimize_excitation(
                robot, n_harmonics=3, maxiter=3, n_samples=40, n_grid=60, n_grid_dynamics=20, seed=0
            )
        conds.append((design.condition_initial, design.condition_optimized))
    (start_exact, exact), (start_rounded, rounded) = conds
    assert start_rounded == pytest.approx(start_exact, rel=SAME_CONDITION)
    assert rounded == pytest.approx(exact, rel=SAME_CONDITION), conds
