"""The isolation's early stop (issue 15, the cost of the tick): the candidate links are fitted from the most
proximal on and the fit stops once the links fitted settle the choice (``reflexarm.control.collision.isolate.settled``
and the C++ core's ``ContactIsolator::settled``). The estimate must be the one the fit of every candidate gives.

Checked three ways: the rule itself against the exhaustive choice on random sequences of link fits (where a
plausible shortcut fails); the Python isolator against itself with the rule switched off, on seeded contacts; the
C++ core against the Python isolator on the links it examined and the best fit over them.
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import reflexarm.control.collision.isolate as isolate_module
from reflexarm.control.collision.contact import Determined
from reflexarm.control.collision.isolate import ContactIsolator, settled
from reflexarm.control.collision.isolate_core import CoreContactIsolator
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots import load_robot
from reflexarm.robots.collision_geometry import link_collision_geometry

SPACING = 0.02
CONTACTS = 120
#: residual noise [Nm] and the levels it is isolated with (as tests/test_isolation_core.py's noisy variant, with
#: a noise large enough that some residuals are explained by no candidate within the tolerance)
NOISE = 0.3
SIGNIFICANCE = 0.5
FIT_TOLERANCE = 0.3
#: best fits compared, core against Python [Nm]: tests/test_isolation_core.py's FIT_ATOL (the core fits in each link's
#: joint frame, Python in the world frame: round-off of an exact fit's ~1e-12 error)
FIT_ATOL = 1e-9


def _choice(errors: list[float], tol: float) -> tuple[int, bool]:
    """The exhaustive rule over every candidate: the first within tol of the best, and whether the best is within
    tol (not NoSingleContact)."""
    best = min(errors)
    return next(i for i, e in enumerate(errors) if e <= best + tol), best <= tol


def test_the_rule_settles_only_what_no_later_link_can_change():
    """On 20 000 random sequences of link fits (values drawn so that ties, near-ties and fits around the tolerance
    are common), wherever ``settled`` stops after a prefix, the choice over the prefix and whether it explains the
    residual equal the exhaustive choice over the whole sequence, whatever the later links hold."""
    rng = np.random.default_rng(5)
    stops = 0
    for _ in range(20_000):
        n = int(rng.integers(1, 8))
        tol = float(rng.choice([0.0, 0.5, 1.0]))
        errors = [float(x) for x in rng.choice([0.0, 0.2, 0.5, 0.9, 1.0, 1.1, 1.5, 3.0], size=n)]
        fits = [SimpleNamespace(best_error=e) for e in errors]
        for k in range(1, n + 1):
            if settled(fits[:k], tol):
                stops += k < n
                assert _choice(errors[:k], tol) == _choice(errors, tol), (errors, tol, k)
                break
    assert stops > 2_000  # the rule did stop early on many sequences


def test_a_shortcut_that_ignores_the_earlier_links_would_choose_wrong():
    """Why the rule looks at the first link within tolerance of the best so far: with fits 1.1, 0.2 and tolerance 1,
    "a link within tolerance was found" would stop and choose the first link (1.1 <= 0.2 + 1), but a third link at
    0.05 makes the second the choice (1.1 > 0.05 + 1). ``settled`` does not stop there."""
    fits = [SimpleNamespace(best_error=e) for e in (1.1, 0.2, 0.05)]
    assert _choice([1.1, 0.2], 1.0)[0] == 0 and _choice([1.1, 0.2, 0.05], 1.0)[0] == 1
    assert not settled(fits[:2], 1.0)
    assert settled(fits[:3], 1.0)


@pytest.fixture(scope="module")
def arms():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {name: load_robot(name) for name in ("atlas_v5_left_arm", "panda")}


def _same(a, b, where):
    assert (a.link, a.link_name, a.determined, a.reason) == (b.link, b.link_name, b.determined, b.reason), where
    assert (a.candidate_links, a.consistent_points) == (b.candidate_links, b.consistent_points), where
    for x, y in ((a.point, b.point), (a.force, b.force)):
        assert (x is None) == (y is None), where
        if x is not None:
            assert np.array_equal(x, y), where
    assert np.array_equal([a.fit_error, a.point_spread], [b.fit_error, b.point_spread], equal_nan=True), where


@pytest.mark.parametrize("noisy", [False, True], ids=["exact", "noisy"])
@pytest.mark.parametrize("name", ["atlas_v5_left_arm", "panda"])
def test_the_early_stop_gives_the_exhaustive_estimate(arms, name, noisy, monkeypatch):
    """Seeded contacts (exact and noisy residuals; Atlas has a link without geometry): the Python isolator equals
    itself with ``settled`` switched off (every candidate fitted, the code before the early stop) bit for bit; the
    C++ core examines the same links and reports the best fit over them. Covered: contacts where the fit stopped
    before the last candidate, and (noisy) where it examined every one and residuals no candidate explains."""
    robot = arms[name]
    geometry = link_collision_geometry(robot, spacing=SPACING)
    truth = link_collision_geometry(robot, spacing=0.004, seed=3)
    if noisy:
        kw = {"significance": np.full(robot.n, SIGNIFICANCE), "fit_tolerance": FIT_TOLERANCE}
    else:
        kw = {"significance": 1e-6}
    py = ContactIsolator(robot, geometry=geometry, **kw)
    core = CoreContactIsolator(robot, geometry=geometry, **kw)
    rng = np.random.default_rng(3)
    examined_counts = []
    record = []

    def counting(fits, tol):
        record.append(len(fits))
        return settled(fits, tol)

    seen, unexplained = set(), 0
    for i, c in enumerate(draw_contacts(robot, truth, CONTACTS, seed=41 + noisy)):
        r = c.torque + (rng.normal(0.0, NOISE, robot.n) if noisy else 0.0)
        record.clear()
        monkeypatch.setattr(isolate_module, "settled", counting)
        early = py.isolate(c.q, r)
        examined = max(record, default=0)
        monkeypatch.setattr(isolate_module, "settled", lambda fits, tol: False)
        every = py.isolate(c.q, r)
        _same(early, every, f"{name} contact {i}")
        seen.add(early.determined)
        unexplained += "explains the residual" in early.reason
        if not early.candidate_links:
            continue
        out = core._core.isolate(np.ascontiguousarray(c.q, dtype=float), np.ascontiguousarray(r, dtype=float))
        assert out["links_examined"] == examined, f"{name} contact {i}"
        fits = py.fit(c.q, r)[:examined]
        best = min(f.best_error for f in fits)
        np.testing.assert_allclose(out["best_fit"], best, rtol=0, atol=FIT_ATOL, err_msg=f"{name} contact {i}")
        examined_counts.append((examined, len(early.candidate_links)))
    stopped = sum(1 for e, c in examined_counts if e < c)
    assert stopped > len(examined_counts) // 4  # the early stop happened often ...
    assert Determined.POINT_AND_FORCE in seen
    if noisy:  # ... and not always: every candidate fitted, some where no single contact explains the residual
        assert any(e == c > 1 for e, c in examined_counts)
        assert unexplained > 0
