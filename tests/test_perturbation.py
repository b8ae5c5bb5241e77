"""Model-error generator: uniform scale factors within +-p, seeded, physically valid inertias."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from reflexarm.errors import ConfigError
from reflexarm.robots import ModelPerturbation, perturb_model
from reflexarm.robots.perturbation import achieved_model_error, measure_model_error, radius_of_gyration


def link_quantities(robot):
    """(mass, COM, principal moments about the COM, principal axes) per link, from Pinocchio directly."""
    out = []
    for j in range(1, robot.pin_model.njoints):
        inertia = robot.pin_model.inertias[j]
        moments, axes = np.linalg.eigh(np.asarray(inertia.inertia))
        out.append((float(inertia.mass), np.asarray(inertia.lever).copy(), moments, axes))
    return out


def test_same_seed_same_model_other_seed_other_model(atlas):
    a = perturb_model(atlas, 0.1, seed=3).inertial_parameters()
    b = perturb_model(atlas, 0.1, seed=3).inertial_parameters()
    c = perturb_model(atlas, 0.1, seed=4).inertial_parameters()
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-6


def test_callers_model_is_not_modified(atlas):
    before = atlas.inertial_parameters().copy()
    fric = atlas.friction.parameters().copy()
    perturb_model(atlas, 0.3, seed=1)
    np.testing.assert_array_equal(atlas.inertial_parameters(), before)
    np.testing.assert_array_equal(atlas.friction.parameters(), fric)


def test_level_zero_is_the_exact_model(atlas):
    # tolerance: one eigendecomposition and re-assembly of a 3x3 inertia per link (double precision)
    np.testing.assert_allclose(
        perturb_model(atlas, 0.0, seed=5).inertial_parameters(), atlas.inertial_parameters(), rtol=1e-12, atol=1e-15
    )


@pytest.mark.parametrize("level", [0.01, 0.1, 0.3])
def test_factors_are_uniform_within_the_level(atlas, level):
    p = ModelPerturbation.draw(atlas.n, level, seed=11)
    allf = np.concatenate([p.mass, p.com.ravel(), p.inertia.ravel(), p.coulomb, p.viscous])
    assert allf.size == 9 * atlas.n  # 7 per link + 2 per joint
    assert np.all(allf >= 1 - level) and np.all(allf <= 1 + level)
    # common random numbers: the same seed gives the same pattern, scaled by the level
    # (atol: (f - 1)/p loses ~1e-16/p of precision to the cancellation in f - 1)
    unit = ModelPerturbation.draw(atlas.n, 0.5, seed=11)
    unit_f = np.concatenate([unit.mass, unit.com.ravel(), unit.inertia.ravel(), unit.coulomb, unit.viscous])
    np.testing.assert_allclose((allf - 1) / level, (unit_f - 1) / 0.5, rtol=0, atol=1e-13)


def test_factors_are_uniformly_distributed():
    # many draws: the unit variables (f - 1)/p fill [-1, 1] uniformly. Kolmogorov-Smirnov distance of
    # 2000 samples from U(-1, 1): its 99.9 % quantile is 1.95/sqrt(2000) = 0.044.
    u = np.concatenate([(ModelPerturbation.draw(7, 0.2, seed=s).mass - 1) / 0.2 for s in range(286)])[:2000]
    x = np.sort(u)
    ks = np.abs((x + 1) / 2 - np.arange(1, x.size + 1) / x.size).max()
    assert ks < 0.044


def test_each_quantity_is_scaled_by_its_own_factor(atlas):
    level = 0.2
    p = ModelPerturbation.draw(atlas.n, level, seed=2)
    pert = p.apply(atlas)
    true_q, pert_q = link_quantities(atlas), link_quantities(pert)
    clipped = p.clipped_links(atlas)
    pert_inertia = [np.asarray(pert.pin_model.inertias[j].inertia) for j in range(1, atlas.n + 1)]
    for k, ((m0, c0, I0, R0), (m1, c1, I1, _)) in enumerate(zip(true_q, pert_q, strict=True)):
        # tolerances: a 3x3 eigendecomposition round trip in double precision
        np.testing.assert_allclose(m1, m0 * p.mass[k], rtol=1e-12, err_msg=f"mass of link {k}")
        # COM: the factor acts on c where |c| >= rho (the paper's relative factor), on rho elsewhere
        rho = np.sqrt(I0.sum() / (2 * m0))
        scale = np.where(np.abs(c0) >= rho, c0, rho)
        np.testing.assert_allclose(c1, c0 + (p.com[k] - 1) * scale, rtol=1e-10, atol=1e-14, err_msg=f"COM of link {k}")
        if k not in clipped:
            # principal moments scaled (eigh returns ascending moments; the factors follow the true order)
            np.testing.assert_allclose(
                np.sort(I1), np.sort(I0 * p.inertia[k]), rtol=1e-9, err_msg=f"principal moments of link {k}"
            )
        # principal axes unchanged: the perturbed tensor is diagonal in the true principal frame
        in_true_axes = R0.T @ pert_inertia[k] @ R0
        np.testing.assert_allclose(in_true_axes, np.diag(np.diag(in_true_axes)), atol=1e-12 * np.abs(I1).max())
    np.testing.assert_allclose(pert.friction.coulomb, atlas.friction.coulomb * p.coulomb, rtol=1e-12)
    np.testing.assert_allclose(pert.friction.viscous, atlas.friction.viscous * p.viscous, rtol=1e-12)


@pytest.mark.parametrize("seed", range(20))
def test_inertias_stay_physically_valid_at_the_largest_level(atlas, seed):
    # 30 % (the top of Fig. 13), and beyond (0.9): positive mass, positive definite inertia about the COM
    # satisfying the triangle inequality, and a positive definite joint-space inertia matrix M(q).
    for level in (0.3, 0.9):
        pert = perturb_model(atlas, level, seed=seed)
        for m, _, moments, _ in link_quantities(pert):
            assert m > 0
            assert np.all(moments > 0)
            a, b, c = np.sort(moments)
            assert c <= (a + b) * (1 + 1e-12)
        q = np.random.default_rng(seed).uniform(atlas.lower_limit, atlas.upper_limit)
        assert np.all(np.linalg.eigvalsh(pert.compute_mass_matrix(q)) > 0)


def test_flat_body_is_clipped_to_the_triangle_inequality(atlas):
    # link 5 (wry) has moments 0.002857, 0.011948, 0.012731: a large factor on the largest and small
    # ones on the others violate the triangle inequality; the clip puts it on the flat-plate limit.
    p = ModelPerturbation.draw(atlas.n, 0.0, 0)
    inertia = p.inertia.copy()
    inertia[4] = [0.2, 0.2, 1.8]
    forced = ModelPerturbation(0.8, 0, p.mass, p.com, inertia, p.coulomb, p.viscous)
    assert 4 in forced.clipped_links(atlas)
    _, _, moments, _ = link_quantities(forced.apply(atlas))[4]
    a, b, c = np.sort(moments)
    np.testing.assert_allclose(c, a + b, rtol=1e-9)


def test_zero_com_coordinates_move_on_the_radius_of_gyration(atlas):
    # shx (link 1) has its COM exactly on the joint origin: a relative factor could not move it. At level
    # p each coordinate moves by (f - 1) * rho with rho the link's radius of gyration.
    inertia = atlas.pin_model.inertias[2]
    assert np.all(np.asarray(inertia.lever) == 0.0)
    rho = radius_of_gyration(float(inertia.mass), np.asarray(inertia.inertia))
    # rho from the principal moments 0.00319, 0.00583, 0.00583 kg m^2 and 3.899 kg (the model file)
    np.testing.assert_allclose(rho, np.sqrt((0.00319 + 2 * 0.00583) / (2 * 3.899)), rtol=2e-3)
    for level in (0.01, 0.1, 0.3):
        p = ModelPerturbation.draw(atlas.n, level, seed=7)
        moved = np.asarray(p.apply(atlas).pin_model.inertias[2].lever)
        np.testing.assert_allclose(moved, (p.com[1] - 1) * rho, rtol=1e-10)
        assert np.abs(moved).max() > 0.25 * level * rho  # the draw of seed 7 is not tiny on all three


def test_perturbed_model_is_a_valid_pinocchio_model(atlas):
    pert = perturb_model(atlas, 0.3, seed=1)
    rng = np.random.default_rng(0)
    q = atlas.home
    dq, ddq = rng.normal(size=(2, atlas.n))
    # regressor identity of the perturbed parameters (atol: sums of ~70 products of O(10) numbers)
    np.testing.assert_allclose(
        pert.compute_regressor(q, dq, ddq) @ pert.inertial_parameters(),
        pert.compute_inverse_dynamics(q, dq, ddq),
        atol=1e-9,
    )
    assert isinstance(pert.pin_model.inertias[1], pin.Inertia)


LEVELS = (0.01, 0.1, 0.3)
SEEDS = range(10)


@pytest.fixture(scope="module")
def achieved(atlas):
    """{(level, seed): ModelErrorSize} over 100 seeded states (the same states for every draw)."""
    return {(p, s): achieved_model_error(atlas, p, seed=s, n_states=100) for p in LEVELS for s in SEEDS}


def test_achieved_error_grows_with_the_level_for_every_seed(achieved):
    # common random numbers: the same seed is the same pattern scaled by p, so the error of g and M grows
    # with p for every draw (first order in p; the p^2 mass x COM terms are 30x smaller at p = 0.3)
    for s in SEEDS:
        g = [achieved[p, s].gravity_median for p in LEVELS]
        m = [achieved[p, s].mass_matrix_median for p in LEVELS]
        assert g[0] < g[1] < g[2], f"seed {s}: gravity error {g} does not grow with {LEVELS}"
        assert m[0] < m[1] < m[2], f"seed {s}: mass-matrix error {m} does not grow with {LEVELS}"


@pytest.mark.parametrize("level", LEVELS)
def test_achieved_error_lies_in_the_derived_band(achieved, level):
    # Band for the median over seeds of (median over states of the relative error) / p.
    # A quantity that is a sum of N contributions a_k, each changed by p * u_k with independent
    # u_k ~ U(-1, 1) (variance 1/3), changes by p * sqrt(sum a_k^2 / 3) (RMS). With the contributions
    # adding up coherently (all links' weights pull down, all inertias are positive), the relative change
    # lies between p / sqrt(3 N) (N equal contributions) and p / sqrt(3) (one contribution dominating).
    # g(q) depends on 4 factors per link (mass, 3 COM coordinates): N = 28; M(q) on all 7: N = 49.
    # Measured (Atlas, these seeds and states): 0.25 p for g and 0.18 p for M at every level.
    n = 7
    g = np.median([achieved[level, s].gravity_median for s in SEEDS]) / level
    m = np.median([achieved[level, s].mass_matrix_median for s in SEEDS]) / level
    assert 1 / np.sqrt(3 * 4 * n) <= g <= 1 / np.sqrt(3), f"gravity error / level = {g:.3f} at p = {level}"
    assert 1 / np.sqrt(3 * 7 * n) <= m <= 1 / np.sqrt(3), f"mass-matrix error / level = {m:.3f} at p = {level}"


def test_measure_model_error_of_the_true_model_is_zero_and_of_a_scaled_mass_is_exact(atlas):
    exact = measure_model_error(atlas, atlas, n_states=20)
    assert exact.gravity_max == 0.0 and exact.mass_matrix_max == 0.0
    # every mass and principal moment x 1.1, COM unchanged: g and M scale by exactly 1.1 (relative error 0.1)
    p = ModelPerturbation.draw(atlas.n, 0.0, 0)
    scaled = ModelPerturbation(0.1, 0, p.mass * 1.1, p.com, p.inertia * 1.1, p.coulomb, p.viscous)
    e = measure_model_error(atlas, scaled.apply(atlas), n_states=20)
    # tolerance: eigendecomposition round trip of each link inertia (double precision)
    np.testing.assert_allclose(
        [e.gravity_median, e.gravity_max, e.mass_matrix_median, e.mass_matrix_max], 0.1, rtol=1e-9
    )


@pytest.mark.parametrize(
    "level, message",
    [
        (-0.05, "model error level must be non-negative (a fraction, 0.1 = +-10 %); got -0.05"),
        (float("nan"), "model error level must be non-negative"),
        (1.0, "model error level must be < 1"),
        ("ten", "model error level must be a number in [0, 1); got 'ten'"),
    ],
)
def test_bad_level_raises_naming_the_value(atlas, level, message):
    with pytest.raises(ConfigError) as e:
        perturb_model(atlas, level, seed=0)
    assert message in str(e.value)


def test_bad_seed_and_mismatched_robot(atlas):
    with pytest.raises(ConfigError, match="seed must be a non-negative integer; got -1"):
        perturb_model(atlas, 0.1, seed=-1)
    with pytest.raises(ConfigError, match="perturbation drawn for 3 joints cannot be applied to a 7-joint robot"):
        ModelPerturbation.draw(3, 0.1, 0).apply(atlas)
