"""Collision isolation and identification: the C++ core against the Python ContactIsolator, ratios in one run.

Timed in the same process on the same seeded contacts (noisy residuals, the default 1 cm candidate spacing),
interleaved round by round so that the load of the machine hits them alike:

- ``python``: ``ContactIsolator.isolate`` (numpy, vectorised over the candidate points);
- ``core``: ``CoreContactIsolator.isolate`` (the same checks and ContactEstimate, the work in C++);
- ``bare``: ``reflexarm._core.ContactIsolator.isolate_only`` (the C++ call alone, no result objects).

    python bench/bench_isolation.py [--rounds 5] [--contacts 100]
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable

import numpy as np

from reflexarm import load_robot
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


def main(rounds: int = 5, contacts: int = 100) -> dict[str, float]:
    print(f"{contacts} noisy contacts x {rounds} rounds per arm, 1 cm candidate spacing (medians of round medians)")
    print(f"{'arm':<20}{'points':>8}{'python':>12}{'core':>12}{'bare':>12}{'python/core':>13}{'python/bare':>13}")
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
        runs = {"python": py.isolate, "core": cc.isolate, "bare": cc._core.isolate_only}
        for fn in runs.values():  # warm-up
            per_call(fn, cases[:10])
        med: dict[str, list[float]] = {k: [] for k in runs}
        for _ in range(rounds):
            for key, fn in runs.items():
                med[key].append(per_call(fn, cases))
        p, c, b = (float(np.median(med[k])) * 1e6 for k in ("python", "core", "bare"))
        points = int(geometry.point_counts().sum())
        print(f"{name:<20}{points:>8}{p:>9.0f} us{c:>9.0f} us{b:>9.0f} us{p / c:>13.1f}{p / b:>13.1f}")
        results.update({f"python_us_{name}": p, f"core_us_{name}": c, f"bare_us_{name}": b,
                        f"python_over_core_{name}": p / c})  # fmt: skip
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--contacts", type=int, default=100)
    args = parser.parse_args()
    main(args.rounds, args.contacts)
