"""The tick with the collision pipeline inside it (issue 15): isolation and identification in update().

A static arm with a seeded contact on a distal link appearing at tick 100 (tau_m = g - J_c^T f), the Controller
with a detection observer (exact, 200 1/s), threshold 11 Nm and the retract reaction, with the links' geometry
(isolation in the ticks) and without. The isolation begins 20 ms after detection (its kinematics), does
``isolation_points_per_tick`` units of its fit per following tick (ReactionSettings; a unit: a candidate point's
constrained fit of pass 2, or 16 points' traces of pass 1), then one tick chooses the link (and its rank), one
estimates its point and force, on the next the estimate is in (and a waiting retract factorises the modal damping's
M(q)), and the retract is planned on the tick after (the solve M11^-1 J^T f and the path, from that tick's q).

Timed two ways, in the same run:

* inside C++ (``reflexarm._core.time_ticks_in_cpp``, issue 15's "in C++ (bench)"): four bound controllers over the
  same states, round after round (the first rotating): with geometry, the baseline, a second copy of each. The
  baseline is the same controller without geometry and with the brake reaction (brake_duration 10 s), so that it
  brakes through the isolation window as the geometry controller (a retract waiting for its estimate) does: the
  retract without geometry would retract from detection and carry the path's extra RNEA in exactly those ticks.
  Each isolation tick against the SAME tick of the baseline, paired (same round), the median of the per-round ratios
  per tick: begin, the largest fit step, choice, estimate, in (+ M(q)), plan; the largest of them; the noise floor
  of that statement (the largest over the same ticks of baseline copy / baseline and geometry copy / geometry).
  Once as run (each tick once: code and data used only after a collision are cold, as they are on a robot), once
  warm (each tick run twice from the same state, the controller copied before and back after the first run,
  untimed, the second run timed: the work added with its data in cache; the copy leaves the geometry controller's
  larger memory a little colder, "pre": its plain ticks before the contact / the baseline's).
* from Python around ``ctrl._core.update`` (what users call; ~0.5 us of binding in a ~6 us tick), each tick's time
  the median over the rounds, over the median plain tick of the controller without geometry (the retract
  reaction): the largest isolation tick beside the largest of the same ticks without geometry (its noise floor),
  the detection tick without geometry (the plain controller's retract planned in it), the median, per tick type.

The ticks it takes (latency at 1 kHz: to the estimate, to the retract's plan) and the same with the whole fit in one
tick (a budget of 10^8 points) for comparison. Beside them the warm cost of a unit: the bound C++ isolator's whole
isolation of the same contact on the controller's geometry, every constrained fit run (fit tolerance 1e9: nothing
pruned, the worst case of a step), repeated back to back, over its constrained fits (pass 1's units charged to
them); and the points per tick that this gives: the most units whose warm cost stays within (BOUND - 1) x the plain
tick. A summary table per arm at the end, with whether every isolation tick stays within issue 15's 1.2 x.

The retract does not wait for the estimate by default (ReactionSettings.retract_waits_for_estimate): it retracts from
detection, the baseline (no geometry) too, and the "in" and "plan" ticks are retract ticks of both; with
--retract-waits the retract brakes until the estimate, factorises M(q) on the "in" tick and is planned on the "plan"
tick, against the braking baseline (above).

    python bench/bench_collision_tick.py [--rounds 21] [--cpp-rounds 51] [--points-per-tick 4 8 16 32] [--retract-waits]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from reflexarm import _core, load_robot
from reflexarm.control import Controller, ReactionSettings
from reflexarm.control.collision.classify import SIGNIFICANCE_SHARE, controller_geometry
from reflexarm.control.collision.isolate_core import CoreContactIsolator
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots import link_collision_geometry

ONSET = 100
DT = 1e-3
#: A budget that fits the whole fit in the tick after it began (the one-shot fit, for comparison).
ONE_SHOT = 10**8
#: Ticks after the fit: the choice of the link, its estimate, the estimate in (a waiting retract factorises M(q)).
FINISHING_TICKS = 3
#: Ticks from the estimate in to the retract's plan (the solve and the path, on the next tick).
PLAN_TICKS = 1
#: The isolation's tick types, in order (the fit: its largest step).
TICK_TYPES = ("begin", "fit", "choice", "estimate", "in", "plan")
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


#: The retract waits for the isolation's estimate (--retract-waits; the default reaction does not).
RETRACT_WAITS = False


def _controller(robot, geometry: object, points_per_tick: int = 24, reaction: str = "retract") -> Controller:
    # brake_duration: the brake baseline brakes through the isolation window (the retract does not use it)
    settings = ReactionSettings(isolation_points_per_tick=points_per_tick, brake_duration=10.0,
                                retract_waits_for_estimate=RETRACT_WAITS)  # fmt: skip
    return Controller(robot, threshold=11.0, reaction=reaction, detection_observer_gain=200.0,
                      observer_discretization="exact", reaction_settings=settings,
                      contact_geometry=geometry)  # fmt: skip


def _baseline(robot) -> Controller:
    """The C++ comparison's controller: no geometry, and through the isolation window what the geometry controller's
    arm does: braking (a retract that waits for the estimate) or retracting from detection (one that does not)."""
    return _controller(robot, None, reaction="retract" if not RETRACT_WAITS else "brake")


def warm_unit_cost(robot, contact, threshold: float = 11.0, calls: int = 200) -> tuple[float, int]:
    """Seconds per constrained fit (a unit of pass 2; pass 1, the begin and the finishing charged to them too), caches
    warm, nothing pruned (the worst case of a step), and the units of the isolation."""
    iso = CoreContactIsolator(robot, significance=SIGNIFICANCE_SHARE * threshold, geometry=controller_geometry(robot),
                              fit_tolerance=1e9)  # fmt: skip
    q, r = np.ascontiguousarray(contact.q, dtype=float), np.ascontiguousarray(contact.torque, dtype=float)
    spread = iso._core.isolate_in_steps(q, r, 1)
    units, examined = int(spread["work"]), int(spread["links_examined"])
    significant = np.flatnonzero(np.abs(r) > SIGNIFICANCE_SHARE * threshold)
    # pass 2's constrained fits: the points of the links examined (the fit stops once they settle the choice)
    fits = int(iso.geometry.point_counts()[significant[-1] :][:examined].sum())
    run, clock = iso._core.isolate_only, time.perf_counter
    ts = np.empty(calls)
    for i in range(calls):
        t0 = clock()
        run(q, r)
        ts[i] = clock() - t0
    return float(np.median(ts)) / max(fits, 1), units


def tick_indices(ev) -> dict[str, object]:
    """The tick indices of each isolation tick type from the geometry controller's event (the fit: a slice)."""
    k_begin = int(round(ev.t_estimate / DT)) - 1  # the tick the isolation began
    k_end = int(round(ev.t_estimated / DT)) - 1  # the tick its estimate came in
    k_fit = k_end - FINISHING_TICKS  # the last fit step
    return {"begin": k_begin, "fit": slice(k_begin + 1, k_fit + 1), "choice": k_fit + 1, "estimate": k_fit + 2,
            "in": k_end, "plan": k_end + PLAN_TICKS}  # fmt: skip


def _largest(per_tick: np.ndarray, index: object) -> float:
    return float(np.max(per_tick[index])) if np.size(per_tick[index]) else float("nan")


def in_cpp(ctrls: list[Controller], states: list[tuple], idx: dict, rounds: int, warm: bool) -> dict[str, float]:
    """Paired per-tick ratios inside C++: ctrls = [geometry, baseline, geometry copy, baseline copy]."""
    cols = list(zip(*states, strict=True))
    arrays = [np.ascontiguousarray(np.array(c, dtype=float)) for c in cols[1:]]
    times, faults = _core.time_ticks_in_cpp([c._core for c in ctrls], np.array(cols[0], dtype=float), *arrays,
                                            rounds, warm)  # fmt: skip
    assert faults == 0, f"{faults} ticks faulted: the timing would not be of the tick"
    T = np.asarray(times)  # (rounds, controllers, ticks)
    ratio = np.median(T[:, 0] / T[:, 1], axis=0)  # geometry / baseline, same tick and round
    floor_base = np.median(T[:, 3] / T[:, 1], axis=0)  # baseline copy / baseline
    floor_geo = np.median(T[:, 2] / T[:, 0], axis=0)  # geometry copy / geometry
    window = slice(idx["begin"], idx["plan"] + 1)
    out = {t: _largest(ratio, idx[t]) for t in TICK_TYPES}
    out["largest"] = float(np.max(ratio[window]))
    out["noise_floor"] = float(max(np.max(floor_base[window]), np.max(floor_geo[window])))
    out["plain_tick_us"] = float(np.median(T[:, 1])) * 1e6
    out["pre"] = float(np.median(ratio[10 : ONSET - 1]))  # plain ticks before the contact, with / without geometry
    return out


def in_python(ctrls: list[Controller], states: list[tuple], idx: dict, rounds: int) -> dict[str, float]:
    """Per-tick medians from Python over the median plain tick: ctrls = [geometry, without geometry (retract)]."""
    a, b = [], []
    for _ in range(rounds):
        a.append(_run(ctrls[0], states))
        b.append(_run(ctrls[1], states))
    ta, tb = np.median(np.array(a), axis=0), np.median(np.array(b), axis=0)
    window = slice(idx["begin"], idx["plan"] + 1)
    plain = np.ones(len(states), bool)
    plain[window] = False
    base = float(np.median(tb))
    k_detect = int(round(ctrls[1].event.t_detect / DT)) - 1  # type: ignore[union-attr]
    out = {t: _largest(ta, idx[t]) / base for t in TICK_TYPES}
    out.update({
        "plain_tick_us": base * 1e6,
        "tick_with_geometry_over_without": float(np.median(ta[plain]) / np.median(tb[plain])),
        "largest": float(ta[window].max() / base),
        # the noise floor of the largest: the same ticks without geometry (no isolation), their largest
        "noise_floor": float(tb[window].max() / base),
        # the controller's own rarely run tick without geometry: the detection, the retract planned in it
        "detection_tick_without_geometry": float(tb[k_detect] / base),
        "median": float(np.median(ta[idx["begin"] + 1 : idx["plan"] + 1]) / base),
    })  # fmt: skip
    return out


def _line(name: str, label: str, how: str, r: dict[str, float]) -> str:
    types = ", ".join(f"{t} {r[t]:.2f}" for t in TICK_TYPES)
    return (f"{name:18s} {label:16s} {how:11s} plain {r['plain_tick_us']:4.1f} us: largest {r['largest']:6.2f} "
            f"(noise floor {r['noise_floor']:.2f}); {types}")  # fmt: skip


def bench_arm(name: str, rounds: int, budgets: list[int], cpp_rounds: int = 51) -> dict[str, dict[str, float]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(name)
    truth = link_collision_geometry(robot, spacing=0.01, seed=3)
    contact = next(c for c in draw_contacts(robot, truth, 1000, seed=1)
                   if c.link >= robot.n - 3 and np.abs(c.torque).max() > 25)  # fmt: skip
    without = _controller(robot, None)
    base, base2 = _baseline(robot), _baseline(robot)
    unit_s, units = warm_unit_cost(robot, contact)
    results: dict[str, dict[str, float]] = {}
    for budget in [*budgets, ONE_SHOT]:
        with_geo, with_geo2 = _controller(robot, "auto", budget), _controller(robot, "auto", budget)
        n_ticks = ONSET + 100 + 4000 // budget + 200  # room for the isolation (a few thousand units at most)
        states = _states(robot, contact, n_ticks)
        _run(with_geo, states)
        ev = with_geo.event
        assert ev is not None and ev.estimate is not None, "the contact was not isolated"
        idx = tick_indices(ev)
        quad = [with_geo, base, with_geo2, base2]
        short = states[: idx["plan"] + 5]  # inside C++: up to the retract's plan (the warm runs copy every tick)
        cpp, warm = in_cpp(quad, short, idx, cpp_rounds, False), in_cpp(quad, short, idx, cpp_rounds, True)
        py = in_python([with_geo, without], states, idx, rounds)
        assert without.event is not None, "the contact was not detected without geometry"
        ticks = idx["in"] - idx["begin"]
        out = {f"cpp_{k}": v for k, v in cpp.items()} | {f"cpp_warm_{k}": v for k, v in warm.items()}
        out |= {f"python_{k}": v for k, v in py.items()}
        out |= {"isolation_ticks": float(ticks), "isolation_latency_ms": ticks * DT * 1e3,
                "retract_plan_latency_ms": (ticks + PLAN_TICKS) * DT * 1e3, "warm_unit_us": unit_s * 1e6,
                "units": float(units),
                # the principle: the most units a tick whose warm cost stays within (BOUND - 1) x the plain tick
                "points_per_tick_within_bound_warm": float(np.floor((BOUND - 1.0) * cpp["plain_tick_us"] * 1e-6
                                                                   / unit_s))}  # fmt: skip
        results[str(budget)] = out
        label = "fit in one tick" if budget == ONE_SHOT else f"{budget:4d} points/tick"
        print(_line(name, label, "C++ as run", cpp))
        print(_line(name, label, "C++ warm", warm) + f" (pre {warm['pre']:.2f})")
        print(_line(name, label, "Python", py) + f", median {py['median']:.2f}, detection tick without geometry "
              f"{py['detection_tick_without_geometry']:.2f}; {ticks} ticks to the estimate, {ticks + PLAN_TICKS} to "
              f"the retract's plan ({ev.estimate.link_name}, {ev.estimate.determined.value})")  # fmt: skip
    return results


def summary(results: dict[str, dict[str, dict[str, float]]]) -> None:
    """Per arm and budget: the largest isolation tick / the same tick of the baseline (C++ as run and warm) or / the
    plain tick (Python), each beside its noise floor, the ticks to the estimate, whether the largest is within BOUND."""
    print(f"\n{'arm':18s} {'points/tick':>11s} {'C++ as run':>15s} {'C++ warm':>15s} {'Python':>15s} {'ticks':>6s} "
          f"<= {BOUND} x (C++ as run / warm / Python)  [largest (noise floor)]")  # fmt: skip
    for name, by_budget in results.items():
        first = next(iter(by_budget.values()))
        print(
            f"{name:18s} warm unit {first['warm_unit_us']:.3f} us a fit (nothing pruned, {first['units']:.0f} units): "
            f"points/tick within {BOUND - 1:.1f} x a plain tick {first['points_per_tick_within_bound_warm']:.0f}"
        )
        for budget, out in by_budget.items():
            label = "fit in 1" if int(budget) == ONE_SHOT else budget
            cells, flags = [], []
            for how in ("cpp", "cpp_warm", "python"):
                largest = out[f"{how}_largest"]
                cells.append(f"{largest:6.2f} ({out[f'{how}_noise_floor']:.2f})")
                flags.append("yes" if largest <= BOUND else "no")
            print(f"{name:18s} {label:>11s} {cells[0]:>15s} {cells[1]:>15s} {cells[2]:>15s} "
                  f"{out['isolation_ticks']:6.0f} {' / '.join(flags)}")  # fmt: skip


def main(
    rounds: int = 21, budgets: list[int] | None = None, cpp_rounds: int = 51
) -> dict[str, dict[str, dict[str, float]]]:
    budgets = [ReactionSettings().isolation_points_per_tick] if budgets is None else budgets
    arms = ("atlas_v5_left_arm", "panda", "iiwa14")
    results = {name: bench_arm(name, rounds, budgets, cpp_rounds) for name in arms}
    summary(results)
    return results


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=21, help="rounds from Python")
    p.add_argument("--cpp-rounds", type=int, default=51, help="rounds inside C++")
    p.add_argument("--points-per-tick", type=int, nargs="+", default=None)
    p.add_argument("--retract-waits", action="store_true", help="the retract waits for the estimate (default: not)")
    args = p.parse_args()
    RETRACT_WAITS = args.retract_waits
    main(args.rounds, args.points_per_tick, args.cpp_rounds)
