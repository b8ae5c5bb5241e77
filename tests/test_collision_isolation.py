"""Collision isolation and identification: against the slow reference, the issue's targets, bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import isolation_reference as ref
from reflexarm.control.collision.contact import Determined
from reflexarm.control.collision.identify import ContactIdentifier, compute_link_kinematics
from reflexarm.control.collision.isolate import ContactIsolator
from reflexarm.errors import ConfigError, SignalError
from reflexarm.experiments.isolation_study import contact_torque, draw_contacts, run_isolation_study
from reflexarm.robots import load_robot, write_ur_like_arm
from reflexarm.robots.collision_geometry import link_collision_geometry

#: Coarse candidate spacing for the reference comparisons (the slow reference loops over every point).
REF_SPACING = 0.03
#: The reference's J_p comes from central differences with step 1e-6: error ~1e-9 relative; the fit errors
#: agree to 1e-6 Nm on residuals of ~10-100 Nm.
FIT_ATOL = 1e-6


@pytest.fixture(scope="module")
def arms(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ur = load_robot(write_ur_like_arm(tmp_path_factory.mktemp("ur")), tip="tool0")
        out = {"atlas": load_robot("atlas_v5_left_arm"), "panda": load_robot("panda"), "ur_like": ur}
        try:
            out["iiwa14"] = load_robot("iiwa14")
        except Exception:  # the built-in iiwa14 comes with another change
            pass
    return out


ARMS = ["atlas", "panda", "ur_like", "iiwa14"]


def _arm(arms, name):
    if name not in arms:
        pytest.skip(f"robot {name} not available")
    return arms[name]


@pytest.mark.parametrize("name", ARMS)
def test_vectorised_fit_matches_reference(arms, name):
    robot = _arm(arms, name)
    geometry = link_collision_geometry(robot, spacing=REF_SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    identifier = ContactIdentifier(robot, geometry)
    weights = np.linspace(1.0, 0.5, robot.n)  # a non-uniform W exercises the weighting
    for c in draw_contacts(robot, truth, 3, seed=11):
        kin = compute_link_kinematics(robot, c.q)
        for link in range(c.link, robot.n):
            if not geometry.links[link].has_geometry:
                continue
            fit = identifier.fit_link(kin, link, c.torque, weights)
            errors, forces = ref.fit_link(robot, geometry, c.q, link, c.torque, weights)
            np.testing.assert_allclose(fit.errors, errors, atol=FIT_ATOL, err_msg=f"{name} link {link}")
            best = int(np.argmin(errors))
            assert fit.errors[fit.best] == pytest.approx(errors[best], abs=FIT_ATOL)
            if fit.link_rank >= 5:  # the force is unique where J_p^T has rank 3
                np.testing.assert_allclose(fit.forces[fit.best], forces[best], atol=1e-4)


class _ShuffledJacobian(ContactIdentifier):
    """Broken variant: two Jacobian columns swapped (a joint-order bug)."""

    def fit_link(self, kin, link, residual, weights=None):
        J = kin.jacobians.copy()
        J[:, :, [0, 1]] = J[:, :, [1, 0]]
        return super().fit_link(type(kin)(kin.q, kin.rotations, kin.origins, J), link, residual, weights)


class _FlippedNormals(ContactIdentifier):
    """Broken variant: inward normals (the friction cone pulls instead of pushing)."""

    def __init__(self, robot, geometry, **kwargs):
        super().__init__(robot, geometry, **kwargs)
        self._generators = [-D for D in self._generators]
        self._facet_normals = [-C for C in self._facet_normals]


def test_reference_comparison_catches_a_shuffled_jacobian(arms):
    robot = arms["panda"]
    geometry = link_collision_geometry(robot, spacing=REF_SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    c = next(c for c in draw_contacts(robot, truth, 20, seed=5) if c.link == 6)
    kin = compute_link_kinematics(robot, c.q)
    broken = _ShuffledJacobian(robot, geometry).fit_link(kin, 6, c.torque)
    errors, _ = ref.fit_link(robot, geometry, c.q, 6, c.torque)
    assert np.abs(broken.errors - errors).max() > 100 * FIT_ATOL


def test_isolation_matches_reference_isolation(arms):
    robot = arms["atlas"]
    geometry = link_collision_geometry(robot, spacing=REF_SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=4)
    iso = ContactIsolator(robot, significance=1e-6, geometry=geometry)
    for c in draw_contacts(robot, truth, 6, seed=21):
        est = iso.isolate(c.q, c.torque)
        expected = ref.isolate_link(robot, geometry, c.q, c.torque, iso.significance, iso.tolerance(c.torque))
        assert est.link == expected


def test_contact_torque_is_the_finite_difference_jacobian(arms):
    """The study's truth J_c^T f against the reference's finite-difference point Jacobian."""
    robot = arms["panda"]
    truth = link_collision_geometry(robot, spacing=0.004, seed=1)
    for c in draw_contacts(robot, truth, 5, seed=2):
        oMi = ref.joint_placements(robot, c.q)[c.link]
        Jp = ref.point_jacobian_fd(robot, c.q, c.link, oMi.actInv(c.point))
        np.testing.assert_allclose(contact_torque(robot, c.q, c.link, c.point, c.force), Jp.T @ c.force, atol=1e-7)
        assert c.force @ c.normal < 0.0  # pushes into the surface
        assert 20.0 <= np.linalg.norm(c.force) <= 100.0


# ---------------------------------------------------------------------- the targets (exact residual)
@pytest.mark.parametrize("name", ARMS)
def test_isolation_and_identification_targets_exact(arms, name):
    robot = _arm(arms, name)
    study = run_isolation_study(robot, contacts=300, seed=7)
    s = study.summary
    assert s["correct_link_rate"] >= 0.99, s
    assert s["point_error_m"]["count"] > 30
    assert s["point_error_m"]["median"] <= 0.02, s["point_error_m"]
    assert s["force_error_pct"]["median"] <= 10.0, s["force_error_pct"]
    assert s["direction_error_deg"]["median"] <= 10.0, s["direction_error_deg"]


def test_flipped_normals_fail_the_targets(arms):
    """Broken variant: with the friction cone turned outwards the point/force targets are missed."""
    robot = arms["panda"]
    geometry = link_collision_geometry(robot)
    truth = link_collision_geometry(robot, spacing=0.004, seed=7)
    good = ContactIsolator(robot, significance=1e-6, geometry=geometry)
    bad = ContactIsolator(robot, significance=1e-6, geometry=geometry)
    bad.identifier = _FlippedNormals(robot, geometry)
    errs = {"good": [], "bad": []}
    for c in draw_contacts(robot, truth, 150, seed=7):
        if c.link < 4:
            continue
        for key, iso in (("good", good), ("bad", bad)):
            est = iso.isolate(c.q, c.torque)
            errs[key].append(np.linalg.norm(est.point - c.point) if est.point is not None else np.inf)
    assert np.median(errs["good"]) <= 0.02
    assert np.median(errs["bad"]) > 0.02


# ---------------------------------------------------------------------- cases
def test_link_without_geometry_gives_point_unknown(arms):
    robot = arms["atlas"]  # l_ufarm (joint 4, l_arm_wry) has no collision geometry
    iso = ContactIsolator(robot, significance=1e-3)
    assert not iso.geometry.links[4].has_geometry
    q = robot.home.copy()
    kin = compute_link_kinematics(robot, q)
    point = kin.origins[4] + kin.rotations[4] @ np.array([0.03, -0.08, 0.04])
    force = np.array([10.0, -20.0, 30.0])
    tau = contact_torque(robot, q, 4, point, force)
    assert abs(tau[4]) > 1e-2
    est = iso.isolate(q, tau)
    assert est.link == 4
    assert est.link_name == "l_ufarm"
    assert est.determined is Determined.LINK_ONLY
    assert est.point is None and est.force is None
    assert est.reason.startswith("point unknown: link 'l_ufarm' (joint 'l_arm_wry') has no collision geometry")


def test_no_significant_residual_is_no_contact(arms):
    robot = arms["panda"]
    iso = ContactIsolator(robot, significance=0.5)
    est = iso.isolate(robot.home, np.full(robot.n, 0.4))
    assert est.point is None and est.force is None and np.isnan(est.fit_error)
    assert est.link == -1 and est.determined is Determined.NONE
    assert "no contact the joints can sense" in est.reason


def test_pure_moment_is_not_explained_by_a_contact_force(arms):
    robot = arms["panda"]
    iso = ContactIsolator(robot, significance=1e-3)
    q = robot.home.copy()
    kin = compute_link_kinematics(robot, q)
    tau = kin.jacobians[6][3:].T @ np.array([0.0, 0.0, 5.0])  # a pure moment on the last link
    est = iso.isolate(q, tau)
    assert est.determined is Determined.LINK_ONLY
    assert est.point is None and est.force is None
    assert "no single contact force" in est.reason


def test_proximal_link_says_what_is_undetermined(arms):
    robot = arms["panda"]
    iso = ContactIsolator(robot, significance=1e-6)
    truth = link_collision_geometry(robot, spacing=0.004, seed=9)
    c = next(c for c in draw_contacts(robot, truth, 50, seed=9) if c.link == 1)
    est = iso.isolate(c.q, c.torque)
    assert est.link == 1
    assert est.determined in (Determined.LINK_ONLY, Determined.FORCE_ONLY)
    assert est.point is None
    assert "point undetermined" in est.reason and "rank 2 (5 needed" in est.reason


# ---------------------------------------------------------------------- bad input
def test_bad_shapes_and_values(arms):
    robot = arms["panda"]
    iso = ContactIsolator(robot, significance=1.0)
    with pytest.raises(
        SignalError, match=r"residual must be a real \(7,\) array \(one value per joint\); got shape \(6,\)"
    ):
        iso.isolate(robot.home, np.zeros(6))
    with pytest.raises(SignalError, match=r"q must be a real \(7,\) array"):
        iso.isolate(np.zeros((7, 1)), np.zeros(7))
    r = np.ones(7)
    r[3] = np.nan
    with pytest.raises(SignalError, match=r"residual must be finite; got .* \(non-finite at joint\(s\) \[3\]\)"):
        iso.isolate(robot.home, r)
    with pytest.raises(SignalError, match="residual must be a real"):
        iso.isolate(robot.home, ["a"] * 7)
    with pytest.raises(ConfigError, match=r"significance must have shape \(7,\)"):
        ContactIsolator(robot, significance=np.ones(3))
    with pytest.raises(ConfigError, match="significance must be positive"):
        ContactIsolator(robot, significance=0.0)
    with pytest.raises(ConfigError, match="fit_tolerance must be a finite number >= 0"):
        ContactIsolator(robot, significance=1.0, fit_tolerance=-1.0)
    with pytest.raises(ConfigError, match="friction_coefficient must be a finite number >= 0"):
        ContactIdentifier(robot, iso.geometry, friction_coefficient=float("nan"))
    with pytest.raises(ConfigError, match="collision geometry has 7 links; robot"):
        ContactIsolator(arms["ur_like"], significance=1.0, geometry=iso.geometry)


def test_noisy_isolation_names_the_link_when_its_own_joint_senses_it(arms):
    """With the paper's noise and +-10 % model error: where the contact link's own joint carries torque above its
    significance the link is named right (the issue's 95 %, measured on 1000 contacts with the CLI: 96-98 %;
    200 contacts have a standard error of ~1.5 points, so 90 % here is > 3 sigma below it); where it does not,
    the residual cannot tell the link from a more proximal one and the estimate's candidate links contain it."""
    study = run_isolation_study(arms["panda"], contacts=200, seed=3, noise=True, model_error=0.1)
    s = study.summary
    assert s["link_sensed"] + s["link_not_sensed"] == s["sensed"]
    assert s["link_not_sensed"] > 0 and s["link_sensed"] > 50, s
    assert s["correct_link_rate_link_sensed"] >= 0.90, s
    hidden = [r for r in study.rows if r["sensed"] and r["own_joint_insignificant"]]
    assert all(r["true_link_in_candidates"] for r in hidden)


def test_the_isolation_study_says_what_its_second_variant_holds(tmp_path, capsys):
    # --model-error alone used to print its variant as "noisy" with nothing saying there was no sensor noise in it
    from reflexarm.cli import main

    assert main(["isolation-study", "--robot", "panda", "--contacts", "10", "--model-error", "10",
                 "--out", str(tmp_path)]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "  noisy: +-10 % model error\n" in out
