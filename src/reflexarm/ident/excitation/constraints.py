"""The limits as the optimizer's constraints: imposed on a grid of times, restored where a 1 kHz check finds a
peak between its points, and the final 1 kHz check of a trajectory.

The limits hold at every instant, a semi-infinite set of constraints; the optimizer sees them on a grid
(:class:`ConstraintGrid`: the linear position, velocity and acceleration limits on one, the torque,
workspace and self-collision bounds of :class:`~.limits.LimitEvaluator` on a coarser one). An iterate
pushed against them peaks between the grid's points. :meth:`ConstraintGrid.restored` checks it at 1 kHz,
adds the peaks' sample times to the grid (the exchange method of semi-infinite programming, Hettich and
Kortanek 1993) and moves the iterate to the nearest point that meets the refined grid, until no peak is
left: the trajectory meets the limits at 1 kHz by construction, at the cost of a small move, instead of
having all its amplitudes scaled down (a peak 2 % over one joint's limit took 2 % off every joint's
motion). :func:`best_at_1khz` keeps the best restored iterate; its final check (:func:`check_at_1khz`)
still shrinks one with a peak left (the guard: no trajectory leaves with a limit exceeded).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.optimize

from reflexarm.errors import IdentificationError
from reflexarm.ident.excitation.cost import Parametrisation
from reflexarm.ident.excitation.limits import ExcitationLimits, LimitEvaluator

__all__ = [
    "CHECK_STEP",
    "FEASIBILITY_TOLERANCE",
    "PEAKS_PER_REFINEMENT",
    "PROJECTION_ITERATIONS",
    "RESTORATIONS",
    "ConstraintGrid",
    "best_at_1khz",
    "shrink_into_limits",
]

#: Scaled constraint margin (O(1) units, see :class:`ConstraintGrid`) an iterate may miss and still
#: count as feasible: the 1 kHz check that follows removes what is left.
FEASIBILITY_TOLERANCE = 1e-6
#: Sampling step of the final check [s] (1 kHz, a torque controller's rate).
CHECK_STEP = 1e-3
#: Most sample times one refinement adds to each of the two grids (the deepest peaks first): each added
#: time of the coarse grid costs one more set of RNEA derivatives per constraint evaluation.
PEAKS_PER_REFINEMENT = 20

#: Refine-and-project steps of :meth:`ConstraintGrid.restored`. A projection holds the peaks at their sample
#: times; they move by a sample or two, so the next step's violations are far smaller (measured on the Panda:
#: margins -0.02 -> -8e-4 -> within, the second move 2 % of the first or less; 1-2 steps per iterate).
RESTORATIONS = 5
#: SLSQP iterations of one projection (a distance to a nearby point: converges in 1-3).
PROJECTION_ITERATIONS = 50
#: SLSQP's ftol of a projection, on 0.5 |y - x|^2 (~1e-6 for a move of 1e-3): the nearest point to ~1e-3 of
#: the move is near enough (the point must meet the constraints, SLSQP's other test at this ftol); 1e-12
#: left SLSQP circling the point reached for 40 iterations (0.2 s each) on the Gen3-like arm.
PROJECTION_FTOL = 1e-9

Margins = tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]


class ConstraintGrid:
    """The limits imposed at the times ``t_linear`` (position, velocity, acceleration: linear in x) and
    ``t_dynamics`` (torque, workspace, self-collision: nonlinear, with exact derivatives), as SLSQP
    constraints with margins >= 0 inside, scaled to O(1)."""

    def __init__(
        self,
        par: Parametrisation,
        limits: ExcitationLimits,
        evaluator: LimitEvaluator,
        t_linear: np.ndarray,
        t_dynamics: np.ndarray,
    ) -> None:
        self.par, self.limits, self.evaluator = par, limits, evaluator
        self.t_linear, self.t_dynamics = np.asarray(t_linear, float), np.asarray(t_dynamics, float)
        self.linear = self._linear_margins()
        self.nonlinear = self._nonlinear_margins()

    @classmethod
    def uniform(
        cls, par: Parametrisation, limits: ExcitationLimits, evaluator: LimitEvaluator, n_linear: int, n_dynamics: int
    ) -> ConstraintGrid:
        """The grids of ``n_linear`` and ``n_dynamics`` equally spaced times over one period."""
        period = 2 * np.pi / par.base_frequency
        return cls(
            par, limits, evaluator, np.arange(n_linear) * period / n_linear, np.arange(n_dynamics) * period / n_dynamics
        )

    def scipy_constraints(self, inside: float = 0.0) -> list[dict[str, Any]]:
        """The constraints margins >= ``inside`` in ``scipy.optimize.minimize``'s form."""
        out = [{"type": "ineq", "fun": lambda x: self.linear[0](x) - inside, "jac": self.linear[1]}]
        if self.nonlinear is not None:
            nonlinear = self.nonlinear
            out.append({"type": "ineq", "fun": lambda x: nonlinear[0](x) - inside, "jac": nonlinear[1]})
        return out

    def feasible(self, x: np.ndarray) -> bool:
        """Whether x meets every constraint of the grid (within :data:`FEASIBILITY_TOLERANCE`)."""
        if not np.all(np.isfinite(x)) or np.min(self.linear[0](x)) < -FEASIBILITY_TOLERANCE:
            return False
        return self.nonlinear is None or bool(np.min(self.nonlinear[0](x)) >= -FEASIBILITY_TOLERANCE)

    def refined(self, x: np.ndarray) -> ConstraintGrid | None:
        """This grid plus the 1 kHz sample times at which a margin of x has a local minimum below zero (at
        most :data:`PEAKS_PER_REFINEMENT` per grid, the deepest first); None when x meets every limit at 1 kHz."""
        trajectory = self.par.trajectory(x)
        t = np.arange(0.0, trajectory.period, CHECK_STEP)
        q, dq, ddq = trajectory.evaluate(t)
        new_linear = _peak_times(t, self._linear_samples(q, dq, ddq))
        new_dynamics = np.zeros(0)
        if self.evaluator.active:
            new_dynamics = _peak_times(t, self.evaluator.margin_samples(q, dq, ddq))
        if new_linear.size == 0 and new_dynamics.size == 0:
            return None
        return ConstraintGrid(
            self.par, self.limits, self.evaluator,
            np.union1d(self.t_linear, new_linear), np.union1d(self.t_dynamics, new_dynamics),
        )  # fmt: skip

    def project(self, x: np.ndarray) -> np.ndarray | None:
        """The point nearest to x (Euclidean in the coefficients) that meets the grid's constraints (SLSQP,
        at most :data:`PROJECTION_ITERATIONS` iterations; aiming :data:`FEASIBILITY_TOLERANCE` inside them, so
        that SLSQP's own tolerance leaves no margin below zero); None if it finds none."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = scipy.optimize.minimize(
                lambda y: 0.5 * float((y - x) @ (y - x)), x, jac=lambda y: y - x, method="SLSQP",
                constraints=self.scipy_constraints(FEASIBILITY_TOLERANCE),
                options={"maxiter": PROJECTION_ITERATIONS, "ftol": PROJECTION_FTOL},
            )  # fmt: skip
        y = np.asarray(res.x)
        return y if self.feasible(y) else None

    def restored(self, x: np.ndarray) -> np.ndarray:
        """x moved onto the limits at 1 kHz: up to :data:`RESTORATIONS` times, refine the grid at its 1 kHz
        peaks (:meth:`refined`) and project it onto the refined grid (:meth:`project`). Returns x as it is
        when it has no peak, and the last point reached otherwise (the final check shrinks what is left)."""
        grid = self
        for _ in range(RESTORATIONS):
            refined = grid.refined(x)
            if refined is None:
                break
            y = refined.project(x)
            if y is None:
                break
            grid, x = refined, y
        return x

    def _linear_samples(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """The linear margins (N, 6 n) at samples (N, n), scaled as :meth:`_linear_margins` scales them."""
        lim = self.limits
        lo, hi, vmax, amax = lim.lower, lim.upper, lim.max_velocity, lim.max_acceleration
        half = 0.5 * (hi - lo)
        return np.concatenate(
            [(hi - q) / half, (q - lo) / half, (vmax - dq) / vmax, (vmax + dq) / vmax, (amax - ddq) / amax,
             (amax + ddq) / amax], axis=1,
        )  # fmt: skip

    def _linear_margins(self) -> Margins:
        """Position, velocity and acceleration limits on the grid: linear in x, margins A x + b >= 0 scaled to O(1)."""
        par, limits, n_grid = self.par, self.limits, self.t_linear.size
        Gq, Gv, Ga = par.linear_maps(self.t_linear)
        G = np.concatenate([Gq.reshape(-1, par.size), Gv.reshape(-1, par.size), Ga.reshape(-1, par.size)])
        lo, hi, vmax, amax = limits.lower, limits.upper, limits.max_velocity, limits.max_acceleration
        rows_hi = np.concatenate([np.tile(hi, n_grid), np.tile(vmax, n_grid), np.tile(amax, n_grid)])
        rows_lo = np.concatenate([np.tile(lo, n_grid), -np.tile(vmax, n_grid), -np.tile(amax, n_grid)])
        scale = np.concatenate([np.tile(0.5 * (hi - lo), n_grid), np.tile(vmax, n_grid), np.tile(amax, n_grid)])
        # margins >= 0 inside the limits, scaled to O(1): (upper - s) / scale and (s - lower) / scale
        A = np.vstack([-G / scale[:, None], G / scale[:, None]])
        b = np.concatenate([rows_hi / scale, -rows_lo / scale])
        return (lambda x: A @ x + b), (lambda x: A)

    def _nonlinear_margins(self) -> Margins | None:
        """Torque, workspace and self-collision margins on the (coarser) grid and their exact derivatives."""
        if not self.evaluator.active:
            return None
        par, evaluator, t_grid = self.par, self.evaluator, self.t_dynamics
        Gq, Gv, Ga = par.linear_maps(t_grid)
        cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

        def both(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            key = x.tobytes()
            if key not in cache:
                cache.clear()
                q, dq, ddq = par.trajectory(x).evaluate(t_grid)
                cache[key] = evaluator.margins(q, dq, ddq, Gq, Gv, Ga)
            return cache[key]

        return (lambda x: both(x)[0]), (lambda x: both(x)[1])


def _peak_times(t: np.ndarray, margins: np.ndarray) -> np.ndarray:
    """The times of the local minima in time (periodic) of each column of ``margins`` (N, m) that lie below
    zero, at most PEAKS_PER_REFINEMENT, the deepest first."""
    if margins.shape[1] == 0:
        return np.zeros(0)
    peak = (margins <= np.roll(margins, 1, axis=0)) & (margins <= np.roll(margins, -1, axis=0))
    peak &= margins < 0.0
    rows = np.flatnonzero(peak.any(axis=1))
    depth = np.where(peak[rows], margins[rows], np.inf).min(axis=1)
    return np.sort(t[rows[np.argsort(depth)[:PEAKS_PER_REFINEMENT]]])


def within(report: dict[str, dict[str, Any]]) -> bool:
    """Whether a :meth:`LimitEvaluator.report` is within the torque limit and above the floor and apart."""
    ok = True
    if "torque" in report:
        ok &= float(report["torque"]["use"]) <= 1.0  # type: ignore[arg-type]
    for key in ("workspace", "self_collision"):
        if key in report:
            ok &= float(report[key]["clearance_m"]) >= 0.0  # type: ignore[arg-type]
    return bool(ok)


def shrink_into_limits(
    par: Parametrisation, x: np.ndarray, evaluator: LimitEvaluator, t: np.ndarray
) -> tuple[np.ndarray, dict[str, dict[str, Any]]]:
    """x with its amplitudes scaled down (bisection on s in [0, 1], 10 steps: s to 1e-3) until the
    nonlinear bounds hold at the times ``t``, and its :meth:`LimitEvaluator.report` there; the rest pose q0
    (s = 0) must meet them."""
    if not evaluator.active:
        return x, {}

    def report(s: float) -> dict[str, dict[str, Any]]:
        q, dq, ddq = par.trajectory(par.scaled(x, s)).evaluate(t)
        return evaluator.report(t, q, dq, ddq)

    full = report(1.0)
    if within(full):
        return x, full
    at_rest = report(0.0)
    if not within(at_rest):
        raise IdentificationError(
            f"no excitation can meet the limits: at rest in the centre pose {np.round(par.unpack(x)[2], 3).tolist()} "
            f"already {at_rest} (choose another --floor, a larger --torque-fraction, or a centre pose)"
        )
    good, bad, kept = 0.0, 1.0, at_rest
    for _ in range(10):
        s = 0.5 * (good + bad)
        r = report(s)
        good, bad, kept = (s, bad, r) if within(r) else (good, s, kept)
    return par.scaled(x, good), kept


def best_at_1khz(
    grid: ConstraintGrid, candidates: list[np.ndarray], log_cond: Callable[[np.ndarray], float]
) -> tuple[np.ndarray, dict[str, dict[str, Any]], float]:
    """Of the candidate iterates (best first), each restored onto the limits at 1 kHz (:meth:`ConstraintGrid.
    restored`) and checked (:func:`check_at_1khz`, which shrinks what is left), and each checked as it is, the
    one with the lowest condition number, with its check's report and the factor the check scaled its amplitudes
    by (1: none).
    A candidate whose cost before restoration is no lower than a checked one's is not tried (the restoration
    moves an iterate to the nearest point within the limits: it changed the condition number by 0.04-0.1 %
    on the Gen3-like arm and the Panda). IdentificationError if none meets the limits at 1 kHz."""
    par, limits, evaluator = grid.par, grid.limits, grid.evaluator
    checked: list[tuple[float, np.ndarray, dict[str, dict[str, Any]], float]] = []
    errors = []
    for candidate in candidates:
        if checked and log_cond(candidate) >= min(c[0] for c in checked):
            break
        # restored onto the refined grid, and as it is: the final check makes either meet every limit at 1 kHz,
        # and a start on the limits' edge (outside the grid's tolerance) can lose more to restoration than to it
        for x in (grid.restored(candidate), candidate):
            try:
                xk, report = check_at_1khz(par, x, limits, evaluator)
            except IdentificationError as e:
                errors.append(e)
                continue
            before = float(np.linalg.norm(np.concatenate(par.unpack(x)[:2], axis=None)))
            scale = float(np.linalg.norm(np.concatenate(par.unpack(xk)[:2], axis=None))) / max(before, 1e-300)
            checked.append((float(log_cond(xk)), xk, report, min(scale, 1.0)))
    if not checked:
        raise errors[0]
    _, x, report, scale = min(checked, key=lambda c: c[0])
    return x, report, scale


def check_at_1khz(
    par: Parametrisation, x: np.ndarray, limits: ExcitationLimits, evaluator: LimitEvaluator
) -> tuple[np.ndarray, dict[str, dict[str, Any]]]:
    """Every limit on the trajectory sampled at 1 kHz; amplitudes shrunk about q0 if a peak fell between
    grid points. Returns x and the nonlinear bounds' report."""
    best = par.trajectory(x)
    period = best.period
    lo, hi = limits.lower, limits.upper
    uses = best.check_limits(lo, hi, limits.max_velocity, limits.max_acceleration)
    if max(uses.values()) > 1.0:
        q0 = par.unpack(x)[2]
        d, _, _ = best.evaluate(np.arange(0.0, period, CHECK_STEP))
        d -= q0  # q0 + s d stays within [lo, hi] for s <= (hi - q0) / max d and (q0 - lo) / max(-d)
        s_pos = min(
            np.min((hi - q0) / np.maximum(d.max(axis=0), 1e-12)), np.min((q0 - lo) / np.maximum(-d.min(axis=0), 1e-12))
        )
        s = min(1.0 / max(uses["velocity"], uses["acceleration"], 1e-12), s_pos)
        x = par.scaled(x, min(s, 1.0))
        uses = par.trajectory(x).check_limits(lo, hi, limits.max_velocity, limits.max_acceleration)
    if max(uses.values()) > 1.0 + 1e-9:
        raise IdentificationError(f"excitation optimization could not meet the limits: {uses}")
    return shrink_into_limits(par, x, evaluator, np.arange(0.0, period, CHECK_STEP))
