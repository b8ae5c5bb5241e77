"""The C++ ContactIsolator (reflexarm._core) against the Python one: same link, same determination, same numbers.

The Python :class:`ContactIsolator` is the reference (itself checked against the slow independent reference in
``test_collision_isolation.py``); :class:`CoreContactIsolator` must return the same :class:`ContactEstimate` on
seeded contacts of every arm, exact and noisy residuals, and refuse bad input with the Python class's messages.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import reflexarm._core as core

from reflexarm.control.collision.contact import Determined
from reflexarm.control.collision.isolate import ContactIsolator
from reflexarm.control.collision.isolate_core import CoreContactIsolator
from reflexarm.errors import ConfigError, SignalError
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots import load_robot, write_ur_like_arm
from reflexarm.robots.collision_geometry import link_collision_geometry

#: Candidate point spacing [m] (coarser than the default 1 cm to keep the Python reference fast; the code paths
#: are the same).
SPACING = 0.02
#: Contacts per arm and variant.
CONTACTS = 200
#: Both compute the same expressions in the same order up to the summation order of numpy's einsum/matmul, so
#: the results differ by round-off only. The point is a candidate point moved by the same R p + o: 1e-12 m is
#: ~1e4 ulp of a 1 m coordinate. The force comes from 2x2/3x3 solves whose condition number on thin links
#: reaches ~1e4: round-off 1e-16 x 1e4 x 100 N ~ 1e-10 N at worst (measured <= 2e-11 N); 1e-8 N leaves margin
#: and is still 1e-10 of the 20-100 N contact forces. The fit error is a norm of ~10-100 Nm residual terms:
#: measured <= 2e-11 Nm, asserted to 1e-9 Nm.
POINT_ATOL = 1e-12
FORCE_ATOL = 1e-8
FIT_ATOL = 1e-9
#: Noisy variant: residual noise [Nm] per joint (Gaussian), its significance level and fit tolerance.
NOISE = 0.05
#: An exact tie: two candidate points that both explain the residual (true fit error 0, a link of rank < 5) score
#: round-off, not 0. The fit's f solves a 3x3 (or 2x2) system whose backward error is a few eps; the error
#: |W (J_p^T f - r)| then carries ~eps |A| |f| / sqrt(lambda_min(A)) = eps sigma_max |f| sqrt(kappa(A)) (sigma the
#: singular values of W J_p^T, kappa(A) capped at 1e10: a worse interior or facet solve is skipped). Measured on
#: Atlas' rank-3 link 2 (|f| ~ 1-3.5 kN, kappa ~ 3e5-2e6): 3e-11 to 1.4e-9 Nm, <= 15 x that estimate; two points
#: tie when their errors differ by at most TIE_ROUNDOFF x the larger estimate (+ FIT_ATOL).
TIE_ROUNDOFF = 100.0
NOISY_SIGNIFICANCE = 0.25
NOISY_FIT_TOLERANCE = 0.3
#: Pass-1 points per unit of the stepped isolation's work (ContactIsolator::kTracePoints).
TRACE_POINTS = 16


@pytest.fixture(scope="module")
def arms(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ur = load_robot(write_ur_like_arm(tmp_path_factory.mktemp("ur")), tip="tool0")
        out = {"atlas": load_robot("atlas_v5_left_arm"), "panda": load_robot("panda"), "ur_like": ur}
        try:
            out["iiwa14"] = load_robot("iiwa14")
        except Exception:  # as test_collision_isolation.py: the built-in iiwa14 may be missing
            pass
    return out


ARMS = ["atlas", "panda", "ur_like", "iiwa14"]


def _arm(arms, name):
    if name not in arms:
        pytest.skip(f"robot {name} not available")
    return arms[name]


def _assert_same(a, b, where, tie=None):
    """``b`` (core) equals ``a`` (Python). ``tie``: when the point is undetermined (LINK_ONLY), a callable checking
    that the core's best point ties with Python's (their scores equal to round-off) where the two picked different
    points of an exact tie: the spread and the numbers of the reason are then measured from another point."""
    assert (b.link, b.link_name, b.determined) == (a.link, a.link_name, a.determined), where
    assert b.candidate_links == a.candidate_links, where
    assert b.consistent_points == a.consistent_points, where
    for label, x, y, atol in (("point", a.point, b.point, POINT_ATOL), ("force", a.force, b.force, FORCE_ATOL)):
        assert (x is None) == (y is None), f"{where}: {label} {x} vs {y}"
        if x is not None:
            np.testing.assert_allclose(y, x, rtol=0, atol=atol, err_msg=f"{where}: {label}")
    np.testing.assert_allclose(b.fit_error, a.fit_error, rtol=0, atol=FIT_ATOL, err_msg=f"{where}: fit_error")
    same_spread = np.isclose(b.point_spread, a.point_spread, rtol=0, atol=POINT_ATOL, equal_nan=True)
    if a.determined is Determined.LINK_ONLY and tie is not None and not (same_spread and b.reason == a.reason):
        tie()
        return
    assert same_spread, f"{where}: spread {b.point_spread} vs {a.point_spread}"
    assert b.reason == a.reason, where


def _fit_roundoff(py, fit, index):
    """eps sigma_max |f| sqrt(kappa(A)) at one candidate point (TIE_ROUNDOFF's estimate of an exact fit's error)."""
    d = fit.points[index] - fit.origin
    jp = (fit.jacobian[:3] + np.cross(fit.jacobian[3:].T, d).T) * py.weights[None, :]  # W J_p^T, transposed
    lam = np.linalg.eigvalsh(jp @ jp.T)
    kappa = min(lam[-1] / lam[0], 1e10) if lam[0] > 0.0 else 1e10
    return float(np.finfo(float).eps * np.sqrt(lam[-1] * kappa) * np.linalg.norm(fit.forces[index]))


def _tie_check(py, cc, q, r, where):
    """The core's best point on the chosen link scores as well as Python's best (an exact tie), in Python's fit."""

    def check():
        out = cc._core.isolate(np.asarray(q, float), np.asarray(r, float))
        fit = next(f for f in py.fit(q, r) if f.link == out["link"])
        if fit.best < 0:
            return
        k = int(np.argmin(np.linalg.norm(fit.points - out["best_point"], axis=1)))
        assert np.linalg.norm(fit.points[k] - out["best_point"]) < POINT_ATOL, where
        tie = FIT_ATOL + TIE_ROUNDOFF * max(_fit_roundoff(py, fit, i) for i in (k, fit.best))
        assert fit.errors[k] <= fit.errors[fit.best] + tie, f"{where}: core best point is no tie"

    return check


@pytest.mark.parametrize("noisy", [False, True], ids=["exact", "noisy"])
@pytest.mark.parametrize("name", ARMS)
def test_core_matches_python(arms, name, noisy):
    robot = _arm(arms, name)
    geometry = link_collision_geometry(robot, spacing=SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    if noisy:
        kw = {"significance": np.full(robot.n, NOISY_SIGNIFICANCE), "fit_tolerance": NOISY_FIT_TOLERANCE}
    else:
        kw = {"significance": 1e-6}  # the study's exact variant
    py = ContactIsolator(robot, geometry=geometry, **kw)
    cc = CoreContactIsolator(robot, geometry=geometry, **kw)
    rng = np.random.default_rng(7)
    seen = set()
    for i, c in enumerate(draw_contacts(robot, truth, CONTACTS, seed=21 + noisy)):
        r = c.torque + (rng.normal(0.0, NOISE, robot.n) if noisy else 0.0)
        a, b = py.isolate(c.q, r), cc.isolate(c.q, r)
        _assert_same(a, b, f"{name} contact {i}", _tie_check(py, cc, c.q, r, f"{name} contact {i}"))
        seen.add(a.determined)
    assert Determined.POINT_AND_FORCE in seen  # the comparison covered the determined case


@pytest.mark.parametrize("edges", [5, 12])
def test_core_matches_python_with_another_pyramid(arms, edges):
    """The core's fit has a compiled form for the default 8-edge pyramid (fitRangeK<8>) and a run-time one for any
    other edge count: the latter against Python too (noisy Panda contacts, so that facets and edges are chosen)."""
    robot = _arm(arms, "panda")
    geometry = link_collision_geometry(robot, spacing=SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    kw = {"significance": np.full(robot.n, NOISY_SIGNIFICANCE), "fit_tolerance": NOISY_FIT_TOLERANCE,
          "cone_edges": edges}  # fmt: skip
    py = ContactIsolator(robot, geometry=geometry, **kw)
    cc = CoreContactIsolator(robot, geometry=geometry, **kw)
    rng = np.random.default_rng(11)
    for i, c in enumerate(draw_contacts(robot, truth, CONTACTS // 4, seed=31)):
        r = c.torque + rng.normal(0.0, NOISE, robot.n)
        a, b = py.isolate(c.q, r), cc.isolate(c.q, r)
        _assert_same(a, b, f"{edges} edges, contact {i}", _tie_check(py, cc, c.q, r, f"{edges} edges, contact {i}"))


def test_no_contact_and_undetectable(arms):
    robot = arms["panda"]
    geometry = link_collision_geometry(robot, spacing=SPACING)
    py = ContactIsolator(robot, significance=1.0, geometry=geometry)
    cc = CoreContactIsolator(robot, significance=1.0, geometry=geometry)
    q = robot.home
    for r in (np.zeros(robot.n), np.full(robot.n, 0.5), np.r_[np.zeros(robot.n - 1), 50.0]):
        _assert_same(py.isolate(q, r), cc.isolate(q, r), f"r = {r}")
    assert cc.isolate(q, np.zeros(robot.n)).determined is Determined.NONE


def test_link_without_geometry(arms):
    """Atlas' link 4 has no collision geometry: the wrench-at-origin score and LINK_ONLY 'point unknown'."""
    robot = arms["atlas"]
    geometry = link_collision_geometry(robot, spacing=SPACING)
    assert 4 in geometry.links_without_geometry()
    py = ContactIsolator(robot, significance=1e-6, geometry=geometry)
    cc = CoreContactIsolator(robot, significance=1e-6, geometry=geometry)
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(100):
        q = rng.uniform(-1.0, 1.0, robot.n)
        r = np.r_[rng.normal(0.0, 20.0, 5), np.zeros(robot.n - 5)]  # joints 0..4 only: a wrench on link 4
        a, b = py.isolate(q, r), cc.isolate(q, r)
        _assert_same(a, b, f"q = {q}")
        hits += "point unknown" in a.reason
    assert hits > 0


def test_weighted_fit_matches(arms):
    """Unequal significance levels: the weighted norm |W (J_p^T f - r)| on both sides."""
    robot = arms["iiwa14"] if "iiwa14" in arms else arms["panda"]
    geometry = link_collision_geometry(robot, spacing=SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=5)
    sig = np.linspace(0.5, 0.1, robot.n)
    py = ContactIsolator(robot, significance=sig, geometry=geometry, fit_tolerance=0.2)
    cc = CoreContactIsolator(robot, significance=sig, geometry=geometry, fit_tolerance=0.2)
    rng = np.random.default_rng(9)
    for i, c in enumerate(draw_contacts(robot, truth, 50, seed=4)):
        r = c.torque + rng.normal(0.0, 0.05, robot.n)
        _assert_same(py.isolate(c.q, r), cc.isolate(c.q, r), f"contact {i}")


# ------------------------------------------------------------------ bad input
@pytest.fixture(scope="module")
def panda_core(arms):
    robot = arms["panda"]
    return CoreContactIsolator(robot, significance=1.0, geometry=link_collision_geometry(robot, spacing=0.05))


def test_wrong_size_is_refused(panda_core):
    with pytest.raises(SignalError, match=r"q must be a real \(7,\) array \(one value per joint\); got shape \(6,\)"):
        panda_core.isolate(np.zeros(6), np.zeros(7))
    with pytest.raises(SignalError, match=r"residual must be a real \(7,\) array .* got shape \(7, 1\)"):
        panda_core.isolate(np.zeros(7), np.zeros((7, 1)))


def test_nan_is_refused(panda_core):
    r = np.ones(7)
    r[2] = np.nan
    with pytest.raises(SignalError, match=r"residual must be finite; got .* \(non-finite at joint\(s\) \[2\]\)"):
        panda_core.isolate(np.zeros(7), r)
    q = np.zeros(7)
    q[6] = np.inf
    with pytest.raises(SignalError, match=r"q must be finite; .* \(non-finite at joint\(s\) \[6\]\)"):
        panda_core.isolate(q, np.ones(7))


def test_core_refuses_bad_input_itself(panda_core):
    """The bare core (no Python checks) refuses instead of computing on bad input."""
    c = panda_core._core
    with pytest.raises(ValueError, match=r"q and residual must be finite vectors of size 7"):
        c.isolate(np.zeros(6), np.zeros(7))
    with pytest.raises(ValueError, match=r"q and residual must be finite vectors of size 7"):
        c.isolate(np.zeros(7), np.full(7, np.nan))
    with pytest.raises(TypeError):  # float32 is refused, not copied silently
        c.isolate(np.zeros(7, dtype=np.float32), np.zeros(7))


def test_bad_configuration(arms):
    robot = arms["panda"]
    geometry = link_collision_geometry(robot, spacing=0.05)
    with pytest.raises(ConfigError, match="significance must be positive"):
        CoreContactIsolator(robot, significance=-1.0, geometry=geometry)
    with pytest.raises(ConfigError, match="cone_edges must be an integer >= 3; got 2"):
        CoreContactIsolator(robot, significance=1.0, geometry=geometry, cone_edges=2)
    text = robot.pin_model.saveToString()
    pts = [np.ascontiguousarray(s.points) for s in geometry.links]
    nrm = [np.ascontiguousarray(s.normals) for s in geometry.links]
    sig = np.ones(robot.n)
    with pytest.raises(ValueError, match=r"surfaces: one per joint expected \(7\); got 6"):
        core.ContactIsolator(text, pts[:6], nrm[:6], sig, 0.0, 0.05, 0.5, 8)
    with pytest.raises(ValueError, match=r"surface of joint 1: \d+ points but \d+ normals"):
        core.ContactIsolator(text, pts, [nrm[0], nrm[0][:1]] + nrm[2:], sig, 0.0, 0.05, 0.5, 8)
    with pytest.raises(ValueError, match=r"significance must be finite and > 0"):
        core.ContactIsolator(text, pts, nrm, np.r_[sig[:6], 0.0], 0.0, 0.05, 0.5, 8)
    with pytest.raises(ValueError, match=r"friction_coefficient must be a finite number >= 0"):
        core.ContactIsolator(text, pts, nrm, sig, 0.0, 0.05, np.nan, 8)


# ------------------------------------------------------------------ the isolation spread over the ticks
#: Point budgets per step: one point, the real-time default's order, and steps that cross links.
BUDGETS = (1, 8, 157)
#: Contacts per arm (each at every budget).
STEPPED_CONTACTS = 300


def _bits(value: object) -> object:
    """A value of the core's estimate dict in a form that compares bit for bit (NaN and -0.0 included)."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return np.asarray(value, dtype=np.float64).tobytes()


@pytest.mark.parametrize("name", ARMS)
def test_isolation_in_steps_equals_one_shot_bitwise(arms, name):
    """The real-time tick's form of the isolation (begin, step(budget) until done, finish) returns isolate()'s
    estimate bit for bit, in ceil(work / budget) steps, work = per candidate link examined with m points ceil(m /
    16) (pass 1, ContactIsolator::kTracePoints points a unit) + m (pass 2), 1 per link examined without geometry
    (the candidates: the most distal joint above its significance and every later one, examined from the first on
    until they settle the choice), on a few hundred seeded contacts per arm, exact and noisy residuals (Atlas: a link
    without geometry)."""
    robot = _arm(arms, name)
    geometry = link_collision_geometry(robot, spacing=SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    significance = NOISY_SIGNIFICANCE
    raw = CoreContactIsolator(robot, significance=significance, geometry=geometry, fit_tolerance=NOISY_FIT_TOLERANCE)
    iso = raw._core  # the bound reflexarm._core.ContactIsolator
    counts = geometry.point_counts()
    rng = np.random.default_rng(11)
    steps_seen = set()
    for i, c in enumerate(draw_contacts(robot, truth, STEPPED_CONTACTS, seed=31)):
        q = np.ascontiguousarray(c.q, dtype=np.float64)
        r = np.ascontiguousarray(c.torque + (rng.normal(0.0, NOISE, robot.n) if i % 2 else 0.0))
        one = {k: _bits(v) for k, v in iso.isolate(q, r).items()}
        significant = np.flatnonzero(np.abs(r) > significance)
        # the links examined (the fit stops once they settle the choice: test_isolation_early_stop.py)
        tail = counts[significant[-1] :][: int(one["links_examined"])] if significant.size else counts[:0]
        work = int(np.sum(np.where(tail > 0, -(-tail // TRACE_POINTS) + tail, 1)))
        pruned = set()
        for budget in BUDGETS:
            spread = iso.isolate_in_steps(q, r, budget)
            assert (spread.pop("work"), spread.pop("steps")) == (work, -(-work // budget)), f"{name} contact {i}"
            pruned.add(spread.pop("pruned"))  # the points go through in the same order whatever the budget
            bad = [k for k, v in spread.items() if _bits(v) != one[k]]
            assert not bad and set(spread) == set(one), f"{name} contact {i}, budget {budget}: {bad} differ"
            steps_seen.add(-(-work // budget))
        assert len(pruned) == 1 and 0 <= pruned.pop() <= int(tail.sum()), f"{name} contact {i}"
    assert max(steps_seen) > 100  # the comparison covered isolations spread over many steps
    with pytest.raises(ValueError, match="point_budget must be >= 1; got 0"):
        iso.isolate_in_steps(q, r, 0)
