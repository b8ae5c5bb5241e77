"""The tick with the collision pipeline inside it (issue 15): isolation and identification in update().

A static arm with a seeded contact on a distal link appearing at tick 100 (tau_m = g - J_c^T f), the Controller
with a detection observer (exact, 200 1/s), threshold 11 Nm and the retract reaction; the core's bare ``update``
timed per call from Python, with the links' geometry (isolation in the ticks) and without, interleaved round by
round (each tick's time the median over the rounds). The isolation begins 20 ms after detection (its kinematics),
does ``isolation_points_per_tick`` units of its fit per following tick (ReactionSettings; a unit: a candidate
point's constrained fit of pass 2, or 16 points' traces of pass 1), then one tick chooses the link (and its rank),
one estimates its point and force, and on the next the estimate is in and the retract is planned from it. Printed
as ratios in the same run: the median tick with geometry / without (the ticks outside the isolation), and over the
isolation's ticks (begin to the estimate) / the median plain tick: the largest (beside the largest of the same
ticks without geometry, the noise floor of a largest, and the detection tick without geometry, which plans the
retract: the plain controller's own rarely run tick), the median, the begin tick, the largest fit step, the three
finishing ticks (choice, estimate, in + retract planned); the ticks it takes (latency at 1 kHz); and the same with
the whole fit in one tick (a budget of 10^8 points) for comparison. Beside them the warm cost of a unit: the bound
C++ isolator's whole isolation of the same contact on the controller's geometry, every constrained fit run (fit
tolerance 1e9: nothing pruned, the worst case of a step), repeated back to back (caches warm), over its constrained
fits (pass 1's units charged to them); and
the points per tick that this principle gives: the most units whose warm cost stays within (BOUND - 1) x the plain
tick. A summary table per arm at the end, with whether the largest isolation tick stays within issue 15's 1.2 x a
plain tick (on a loaded machine the noise floor alone can exceed it: more rounds).

    python bench/bench_collision_tick.py [--rounds 5] [--points-per-tick 4 8 16 32]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from reflexarm import load_robot
from reflexarm.control import Controller, ReactionSettings
from reflexarm.control.collision.classify import SIGNIFICANCE_SHARE, controller_geometry
from reflexarm.control.collision.isolate_core import CoreContactIsolator
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots import link_collision_geometry

ONSET = 100
DT = 1e-3
#: A budget that fits the whole fit in the tick after it began (the one-shot fit, for comparison).
ONE_SHOT = 10**8
#: Ticks after the fit: the choice of the link, its estimate, the estimate in with the retract planned.
FINISHING_TICKS = 3
#: Issue 15's bound on a tick with isolation and identification, x the plain tick.
BOUND = 1.2


def _states(robot, contact, n_ticks: int) -> list[tuple]:
    g = robot.compute_gravity(contact.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    out = []
    for k in range(n_ticks):
        tau_m = g - (contact.torque if k >= ONSET else 0.0)
        out.append(((k + 1) * DT, contact.q, zeros, tau_m, np.zeros(6), gravity, contact.q, zeros, zeros))
    return out


def _run(ctrl: Controller, states: list[tuple]) -> np.ndarray:
    ctrl.reset()
    update, clock = ctrl._core.update, time.perf_counter
    ts = np.empty(len(states))
    for i, a in enumerate(states):
        t0 = clock()
        update(*a)
        ts[i] = clock() - t0
    return ts


def _controller(robot, geometry: object, points_per_tick: int = 24) -> Controller:
    return Controller(robot, threshold=11.0, reaction="retract", detection_observer_gain=200.0,
                      observer_discretization="exact",
                      reaction_settings=ReactionSettings(isolation_points_per_tick=points_per_tick),
                      contact_geometry=geometry)  # fmt: skip


def warm_unit_cost(robot, contact, threshold: float = 11.0, calls: int = 200) -> tuple[float, int]:
    """Seconds per constrained fit (a unit of pass 2; pass 1, the begin and the finishing charged to them too), caches
    warm, nothing pruned (the worst case of a step), and the units of the isolation."""
    iso = CoreContactIsolator(robot, significance=SIGNIFICANCE_SHARE * threshold, geometry=controller_geometry(robot),
                              fit_tolerance=1e9)  # fmt: skip
    q, r = np.ascontiguousarray(contact.q, dtype=float), np.ascontiguousarray(contact.torque, dtype=float)
    units = int(iso._core.isolate_in_steps(q, r, 1)["work"])
    significant = np.flatnonzero(np.abs(r) > SIGNIFICANCE_SHARE * threshold)
    fits = int(iso.geometry.point_counts()[significant[-1] :].sum())  # pass 2's constrained fits
    run, clock = iso._core.isolate_only, time.perf_counter
    ts = np.empty(calls)
    for i in range(calls):
        t0 = clock()
        run(q, r)
        ts[i] = clock() - t0
    return float(np.median(ts)) / max(fits, 1), units


def bench_arm(name: str, rounds: int, budgets: list[int]) -> dict[str, dict[str, float]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(name)
    truth = link_collision_geometry(robot, spacing=0.01, seed=3)
    contact = next(c for c in draw_contacts(robot, truth, 1000, seed=1)
                   if c.link >= robot.n - 3 and np.abs(c.torque).max() > 25)  # fmt: skip
    without = _controller(robot, None)
    unit_s, units = warm_unit_cost(robot, contact)
    results: dict[str, dict[str, float]] = {}
    for budget in [*budgets, ONE_SHOT]:
        with_geo = _controller(robot, "auto", budget)
        n_ticks = ONSET + 100 + 4000 // budget + 200  # room for the isolation (a few thousand units at most)
        states = _states(robot, contact, n_ticks)
        a, b = [], []
        for _ in range(rounds):
            a.append(_run(with_geo, states))
            b.append(_run(without, states))
        ev = with_geo.event
        assert ev is not None and ev.estimate is not None, "the contact was not isolated"
        assert without.event is not None, "the contact was not detected without geometry"
        k_detect = int(round(without.event.t_detect / DT)) - 1
        k_begin = int(round(ev.t_estimate / DT)) - 1  # the tick the isolation began
        k_end = int(round(ev.t_estimated / DT)) - 1  # the tick its estimate came in
        ta, tb = np.median(np.array(a), axis=0), np.median(np.array(b), axis=0)
        plain = np.ones(len(states), bool)
        plain[k_begin : k_end + 1] = False
        base = float(np.median(tb))
        k_fit = k_end - FINISHING_TICKS  # the last fit step
        out = {
            "plain_tick_us": base * 1e6,
            "tick_with_geometry_over_without": float(np.median(ta[plain]) / np.median(tb[plain])),
            "largest_isolation_tick_us": float(ta[k_begin : k_end + 1].max() * 1e6),
            "largest_isolation_tick_over_plain": float(ta[k_begin : k_end + 1].max() / base),
            # the noise floor of the largest: the same ticks without geometry (no isolation), their largest
            "largest_plain_tick_over_plain": float(tb[k_begin : k_end + 1].max() / base),
            # the controller's own rarely run tick without geometry: the detection, the retract planned in it
            "detection_tick_without_geometry_over_plain": float(tb[k_detect] / base),
            "median_isolation_tick_over_plain": float(np.median(ta[k_begin + 1 : k_end + 1]) / base),
            "begin_tick_over_plain": float(ta[k_begin] / base),
            "largest_fit_step_over_plain": float(ta[k_begin + 1 : k_fit + 1].max() / base),
            "choice_tick_over_plain": float(ta[k_fit + 1] / base),
            "estimate_tick_over_plain": float(ta[k_fit + 2] / base),
            "finishing_tick_over_plain": float(ta[k_end] / base),  # the estimate in, the retract planned
            "isolation_ticks": float(k_end - k_begin),
            "isolation_latency_ms": (k_end - k_begin) * DT * 1e3,
            "warm_unit_us": unit_s * 1e6,
            "units": float(units),
            # the principle: the most units a tick whose warm cost stays within (BOUND - 1) x the plain tick
            "points_per_tick_within_bound_warm": float(np.floor((BOUND - 1.0) * base / unit_s)),
        }
        results[str(budget)] = out
        label = "fit in one tick" if budget == ONE_SHOT else f"{budget:4d} points/tick"
        print(f"{name:18s} {label:16s} plain {out['plain_tick_us']:5.1f} us, others with/without geometry "
              f"{out['tick_with_geometry_over_without']:.2f}; isolation: largest tick "
              f"{out['largest_isolation_tick_over_plain']:6.2f} x plain (without geometry "
              f"{out['largest_plain_tick_over_plain']:.2f}, its detection tick "
              f"{out['detection_tick_without_geometry_over_plain']:.2f}; median "
              f"{out['median_isolation_tick_over_plain']:.2f}; begin {out['begin_tick_over_plain']:.2f}, fit step "
              f"{out['largest_fit_step_over_plain']:.2f}, choice {out['choice_tick_over_plain']:.2f}, estimate "
              f"{out['estimate_tick_over_plain']:.2f}, in + retract {out['finishing_tick_over_plain']:.2f}), "
              f"{k_end - k_begin:4d} ticks = {out['isolation_latency_ms']:5.0f} ms after it began "
              f"({ev.estimate.link_name}, {ev.estimate.determined.value})")  # fmt: skip
    return results


def summary(results: dict[str, dict[str, dict[str, float]]]) -> None:
    """Per arm and budget: the largest and the median isolation tick / plain, the ticks to the estimate, and
    whether the largest stays within BOUND."""
    print(f"\n{'arm':18s} {'points/tick':>11s} {'largest/plain':>13s} {'(without geometry)':>18s} "
          f"{'(its detection)':>15s} {'median/plain':>12s} {'ticks':>6s} <= {BOUND} x")  # fmt: skip
    for name, by_budget in results.items():
        first = next(iter(by_budget.values()))
        print(
            f"{name:18s} warm unit {first['warm_unit_us']:.3f} us a fit (nothing pruned, {first['units']:.0f} units): "
            f"points/tick within {BOUND - 1:.1f} x a plain tick {first['points_per_tick_within_bound_warm']:.0f}"
        )
        for budget, out in by_budget.items():
            label = "fit in 1" if int(budget) == ONE_SHOT else budget
            largest = out["largest_isolation_tick_over_plain"]
            print(f"{name:18s} {label:>11s} {largest:13.2f} {out['largest_plain_tick_over_plain']:18.2f} "
                  f"{out['detection_tick_without_geometry_over_plain']:15.2f} "
                  f"{out['median_isolation_tick_over_plain']:12.2f} {out['isolation_ticks']:6.0f} "
                  f"{'yes' if largest <= BOUND else 'no'}")  # fmt: skip


def main(rounds: int = 5, budgets: list[int] | None = None) -> dict[str, dict[str, dict[str, float]]]:
    budgets = [ReactionSettings().isolation_points_per_tick] if budgets is None else budgets
    results = {name: bench_arm(name, rounds, budgets) for name in ("atlas_v5_left_arm", "panda", "iiwa14")}
    summary(results)
    return results


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--points-per-tick", type=int, nargs="+", default=None)
    args = p.parse_args()
    main(args.rounds, args.points_per_tick)
