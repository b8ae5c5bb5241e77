"""Collision isolation and identification: the C++ core against the Python ContactIsolator, ratios in one run.

Timed in the same process on the same seeded contacts (noisy residuals, the default 1 cm candidate spacing),
interleaved round by round so that the load of the machine hits them alike:

- ``python``: ``ContactIsolator.isolate`` (numpy, vectorised over the candidate points);
- ``core``: ``CoreContactIsolator.isolate`` (the same checks and ContactEstimate, the work in C++);
- ``bare``: ``reflexarm._core.ContactIsolator.isolate_only`` (the C++ call alone, no result objects).

And the early stop (the candidate links fitted until they settle the choice, ``isolate.settled``): the C++ work in
units (``isolate_in_steps``' ``work``) over the work of fitting every candidate link (its formula: ceil(m / 16) + m
per link with m points, 1 without geometry), summed over the contacts, beside the controller's 2 cm geometry's; and
``python``'s time over the same isolator with the stop switched off (every candidate fitted, as before it).

    python bench/bench_isolation.py [--rounds 5] [--contacts 100]
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable

import numpy as np

import reflexarm.control.collision.isolate as isolate_module
from reflexarm import load_robot
from reflexarm.control.collision.classify import controller_geometry
from reflexarm.control.collision.isolate import ContactIsolator
from reflexarm.control.collision.isolate_core import CoreContactIsolator
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots.collision_geometry import link_collision_geometry

ARMS = ("atlas_v5_left_arm", "panda", "iiwa14")
NOISE = 0.05  # [Nm] residual noise per joint
SIGNIFICANCE = 0.25  # [Nm]
FIT_TOLERANCE = 0.3


def per_call(fn: Callable[[np.ndarray, np.ndarray], object], cases: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Median wall time of one call over the cases [s]."""
    clock = time.perf_counter
    ts = np.empty(len(cases))
    for i, (q, r) in enumerate(cases):
        t0 = clock()
        fn(q, r)
        ts[i] = clock() - t0
    return float(np.median(ts))


def work_share(robot, geometry, cases: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """The early stop's work over the work of fitting every candidate link, summed over the cases (units)."""
    core = CoreContactIsolator(robot, significance=SIGNIFICANCE, geometry=geometry, fit_tolerance=FIT_TOLERANCE)
    counts = geometry.point_counts()
    done = every = 0
    for q, r in cases:
        significant = np.flatnonzero(np.abs(r) > SIGNIFICANCE)
        if not significant.size:
            continue
        tail = counts[significant[-1] :]
        every += int(np.sum(np.where(tail > 0, -(-tail // 16) + tail, 1)))
        done += int(core._core.isolate_in_steps(np.ascontiguousarray(q, dtype=float), r, 10**8)["work"])
    return done / max(every, 1)


def without_stop(py: ContactIsolator) -> Callable[[np.ndarray, np.ndarray], object]:
    """``py.isolate`` with the early stop switched off (every candidate link fitted)."""

    def run(q: np.ndarray, r: np.ndarray) -> object:
        rule, isolate_module.settled = isolate_module.settled, lambda fits, tol: False  # type: ignore[assignment]
        try:
            return py.isolate(q, r)
        finally:
            isolate_module.settled = rule  # type: ignore[assignment]

    return run


def main(rounds: int = 5, contacts: int = 100) -> dict[str, float]:
    print(f"{contacts} noisy contacts x {rounds} rounds per arm, 1 cm candidate spacing (medians of round medians)")
    print(f"{'arm':<20}{'points':>8}{'python':>12}{'core':>12}{'bare':>12}{'python/core':>13}{'python/bare':>13}"
          f"{'python/every':>14}{'work 1 cm':>11}{'work 2 cm':>11}")  # fmt: skip
    results: dict[str, float] = {}
    for name in ARMS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                robot = load_robot(name)
            except Exception:  # an arm missing from this install
                continue
        geometry = link_collision_geometry(robot)
        truth = link_collision_geometry(robot, spacing=0.004, seed=3)
        kw = {"significance": SIGNIFICANCE, "geometry": geometry, "fit_tolerance": FIT_TOLERANCE}
        py, cc = ContactIsolator(robot, **kw), CoreContactIsolator(robot, **kw)
        rng = np.random.default_rng(0)
        cases = [
            (c.q, np.ascontiguousarray(c.torque + rng.normal(0.0, NOISE, robot.n)))
            for c in draw_contacts(robot, truth, contacts, seed=1)
        ]
        runs = {"python": py.isolate, "core": cc.isolate, "bare": cc._core.isolate_only, "every": without_stop(py)}
        for fn in runs.values():  # warm-up
            per_call(fn, cases[:10])
        med: dict[str, list[float]] = {k: [] for k in runs}
        for _ in range(rounds):
            for key, fn in runs.items():
                med[key].append(per_call(fn, cases))
        p, c, b, e = (float(np.median(med[k])) * 1e6 for k in ("python", "core", "bare", "every"))
        points = int(geometry.point_counts().sum())
        w1 = work_share(robot, geometry, cases)
        g2 = controller_geometry(robot)
        w2 = work_share(robot, g2, cases) if g2 is not None else float("nan")
        print(f"{name:<20}{points:>8}{p:>9.0f} us{c:>9.0f} us{b:>9.0f} us{p / c:>13.1f}{p / b:>13.1f}"
              f"{p / e:>14.2f}{w1:>11.2f}{w2:>11.2f}")  # fmt: skip
        results.update({f"python_us_{name}": p, f"core_us_{name}": c, f"bare_us_{name}": b,
                        f"python_over_core_{name}": p / c, f"python_over_every_{name}": p / e,
                        f"work_share_{name}": w1, f"work_share_2cm_{name}": w2})  # fmt: skip
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--contacts", type=int, default=100)
    args = parser.parse_args()
    main(args.rounds, args.contacts)
