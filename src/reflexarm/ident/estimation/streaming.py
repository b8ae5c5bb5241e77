"""Identification from table logs read in blocks: memory bounded by the normal equations and a block.

:func:`identify_dynamics_streamed` is :func:`~reflexarm.logs.load_log`, the plausibility checks,
:func:`~reflexarm.logs.preprocess_log` and :func:`~reflexarm.ident.identify_dynamics` (one per method) on logs
too long to hold: each log is scanned once for its time stamps (:mod:`reflexarm.logs.blocks`), then read
once more block by block; every preprocessed block is checked against the robot's limits and reduced into
each method's per-joint normal equations (:mod:`._regression`), and the solve reads only those
(:mod:`._estimate`). The whole-log checks run on statistics gathered over the blocks: the unit checks of
:mod:`reflexarm.logs.units` on the windows' position changes and velocity integrals (summed in the same
order as over the whole log) and on the same evenly spread model samples. Whole-log arrays kept: the time
vectors (8 bytes a sample each).

The result equals the in-memory path's up to the preprocessing's rounding (see :mod:`reflexarm.logs.blocks`:
the Butterworth filter in transfer-function form carries a rounding noise of about 1e-10 relative at
fc / fs = 0.02, which a window started elsewhere reproduces only to that level) and the summation order of
the normal equations.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Literal

import numpy as np
import numpy.typing as npt

from reflexarm.ident._blas_threads import DEFAULT_BLAS_THREADS, blas_threads
from reflexarm.ident.estimation._estimate import estimate
from reflexarm.ident.estimation._regression import add_rows, check_log, setup_problem
from reflexarm.ident.estimation.base_parameters import BaseParameters
from reflexarm.ident.estimation.inertia_determinacy import filtered_rows_factor
from reflexarm.ident.estimation.result import DynamicsIdentification
from reflexarm.ident.friction.parameters import FrictionParameters
from reflexarm.logs.blocks import DEFAULT_BLOCK_ROWS, StreamedTable, preprocessed_blocks, shifted_rows
from reflexarm.logs.bounds import _SHOWN, BadSample
from reflexarm.logs.preprocessing import DEFAULT_CUTOFF_HZ, PreprocessingPlan, plan_preprocessing
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = ["StreamedUnitsCheck", "identify_dynamics_streamed"]


def identify_dynamics_streamed(
    robot: RobotModel,
    tables: Sequence[StreamedTable],
    methods: Sequence[str],
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    block_rows: int = DEFAULT_BLOCK_ROWS,
    friction: FrictionParameters | CoulombViscousFriction | None = None,
    offset: bool = False,
    noise_variance: npt.ArrayLike | Literal["estimate"] | None = "estimate",
    base: BaseParameters | None = None,
    condition_limit: float = 1e3,
    min_speed: float = 0.0,
    threads: int | None = DEFAULT_BLAS_THREADS,
    wrench: Literal["auto", "include", "exclude"] = "auto",
) -> dict[str, DynamicsIdentification]:
    """One identification per method (the options as :func:`~reflexarm.ident.identify_dynamics`'s) from scanned
    table logs (:func:`~reflexarm.logs.block_scan.scan_table`), preprocessed with ``cutoff_hz`` as
    :func:`~reflexarm.logs.preprocess_log` does, in blocks of ``block_rows`` samples; the raw and the
    preprocessed logs are held against the robot as loading and identification do."""
    with blas_threads(threads):
        plans = [
            plan_preprocessing(tb.t, tb.source, cutoff_hz=cutoff_hz, has_ddq=tb.has_ddq, has_wrench=tb.has_wrench)
            for tb in tables
        ]
        for tb in tables:
            check_log(tb.source, tb.n, True, robot)
        has_any_wrench = any(tb.has_wrench for tb in tables)
        problems = [
            setup_problem(robot, m, friction, offset, noise_variance, base, min_speed, wrench, has_any_wrench)
            for m in methods
        ]
        steps = []
        for tb, plan in zip(tables, plans, strict=True):
            grid = _grid(plan)
            steps.append(float(np.median(np.diff(grid))))
            for block in checked_blocks(tb, plan, robot, block_rows, grid):
                add_rows(problems, block)
        row_corr = filtered_rows_factor(steps, cutoff_hz)
        return {
            pb.method: estimate(
                pb,
                condition_limit=condition_limit,
                row_correlation=row_corr,
                suspects=lambda: _suspects(tables, plans, block_rows),
                has_any_wrench=has_any_wrench,
            )
            for pb in problems
        }


def _grid(plan: PreprocessingPlan) -> np.ndarray:
    """The preprocessed log's time (N,) [s]."""
    return np.concatenate([s.t0 + s.period * np.arange(s.k) for s in plan.segments])


def checked_blocks(
    table: StreamedTable,
    plan: PreprocessingPlan,
    robot: RobotModel,
    block_rows: int,
    grid: np.ndarray,
    check_states: bool = True,
) -> Iterator[RobotLog]:
    """The preprocessed blocks of ``table``; the raw and (``check_states``) the preprocessed log held against
    ``robot``'s limits block by block and, once all blocks are read, to the unit checks."""
    from reflexarm.logs.plausibility import check_samples_against_robot

    raw_units = StreamedUnitsCheck(table.source, table.t, table.has_ddq)
    pre_units = StreamedUnitsCheck(table.source, grid, True)

    def check(start: int, lg: RobotLog, units: StreamedUnitsCheck) -> None:
        with shifted_rows(np.arange(start, start + len(lg))):
            check_samples_against_robot(lg.source, lg.t, lg.q, lg.dq, lg.measured_torque, robot, units=False)
        units.add(start, lg)

    def raw_hook(start: int, lg: RobotLog) -> None:
        check(start, lg, raw_units)

    start = 0
    for block in preprocessed_blocks(table, plan, block_rows, raw_hook=raw_hook):
        if check_states:
            check(start, block, pre_units)
        start += len(block)
        yield block
    raw_units.finish(robot)
    if check_states:
        pre_units.finish(robot)


class StreamedUnitsCheck:
    """:func:`~reflexarm.logs.units.check_units` on a log added block by block, in order: the windows' delta q
    and integrals of dq (the integral summed in the whole log's order, so the same numbers) and the model
    samples gathered as the blocks pass."""

    def __init__(self, source: str, t: np.ndarray, has_ddq: bool) -> None:
        from reflexarm.logs import units

        self.source, self.t = source, t
        self.edges = units._windows(t)
        rows = np.unique(np.linspace(0, t.size - 1, min(t.size, units._MODEL_SAMPLES)).round().astype(int))
        self.rows, self.lo, self.hi = rows, rows, rows
        if not has_ddq:
            k = max(int(round(0.5 * units.WINDOW / float(np.median(np.diff(t))))), 1)
            self.lo, self.hi = np.maximum(rows - k, 0), np.minimum(rows + k, t.size - 1)
        self.need = np.unique(np.r_[rows, self.lo, self.hi])
        self.has_ddq = has_ddq
        self.gathered: dict[str, list[np.ndarray]] = {"q": [], "dq": [], "tau": [], "ddq": []}
        self.q_edges: list[np.ndarray] = []
        self.i_edges: list[np.ndarray] = []
        self.carry: tuple[np.ndarray, np.ndarray, float] | None = None  # (integral, dq, t) at the last row added

    def add(self, start: int, lg: RobotLog) -> None:
        m = len(lg)
        if self.carry is None:
            inc = 0.5 * (lg.dq[1:] + lg.dq[:-1]) * np.diff(lg.t)[:, None]
            integral = np.r_[np.zeros((1, lg.n)), np.cumsum(inc, axis=0)]
        else:
            last, dq_last, t_last = self.carry
            inc = 0.5 * (lg.dq + np.vstack([dq_last, lg.dq[:-1]])) * np.diff(np.r_[t_last, lg.t])[:, None]
            integral = np.cumsum(np.vstack([last, inc]), axis=0)[1:]
        self.carry = (integral[-1:], lg.dq[-1:], lg.t[-1])
        e = self.edges[(self.edges >= start) & (self.edges < start + m)] - start
        self.q_edges.append(lg.q[e])
        self.i_edges.append(integral[e])
        r = self.need[(self.need >= start) & (self.need < start + m)] - start
        for name, a in (("q", lg.q), ("dq", lg.dq), ("tau", lg.measured_torque), ("ddq", lg.ddq)):
            if a is not None:
                self.gathered[name].append(a[r])

    def finish(self, robot: RobotModel) -> None:
        """Raise :class:`~reflexarm.errors.ImplausibleDataError` as :func:`~reflexarm.logs.units.check_units`."""
        from reflexarm.logs import units

        if self.edges.size >= units.MIN_WINDOWS + 1:
            moved, expected = np.diff(np.vstack(self.q_edges), axis=0), np.diff(np.vstack(self.i_edges), axis=0)
            units.refuse_inconsistent(self.source, robot, float(self.t[0]), units.judge_consistency(moved, expected))
        at = {name: np.vstack(v) for name, v in self.gathered.items() if v}
        pos = np.searchsorted(self.need, self.rows)
        if self.has_ddq:
            acc = at["ddq"][pos]
        else:
            lo, hi = np.searchsorted(self.need, self.lo), np.searchsorted(self.need, self.hi)
            span = (self.t[self.hi] - self.t[self.lo])[:, None]
            acc = np.where(span > 0, (at["dq"][hi] - at["dq"][lo]) / np.where(span > 0, span, 1.0), 0.0)
        t0 = float(self.t[self.rows[0]])
        units.check_model_samples(self.source, robot, t0, at["q"][pos], at["dq"][pos], at["tau"][pos], acc)


def _suspects(tables: Sequence[StreamedTable], plans: Sequence[PreprocessingPlan], block_rows: int) -> list[BadSample]:
    """:func:`~reflexarm.logs.plausibility.likely_bad_rows` over the blocks (each block's 99th percentiles stand
    for its columns'), read once more: only when a result is not finite."""
    from reflexarm.logs.plausibility import likely_bad_rows

    scored: list[tuple[float, BadSample]] = []
    for tb, plan in zip(tables, plans, strict=True):
        start = 0
        for block in preprocessed_blocks(tb, plan, block_rows):
            for s in likely_bad_rows([block]):
                score = abs(s.value) / max(s.reference, 1e-12) if np.isfinite(s.value) else np.inf
                scored.append((score, s._replace(row=s.row + start)))
            start += len(block)
    scored.sort(key=lambda x: -x[0])
    return [s for _, s in scored[:_SHOWN]]
