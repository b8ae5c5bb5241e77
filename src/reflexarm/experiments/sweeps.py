"""Sweeps at scale: many independent closed-loop runs, in parallel, resumable; Figs. 13 and 14.

The machinery (:func:`run_sweep`) is generic: a list of :class:`SweepTask`, a picklable run function
``run_fn(task, context) -> dict`` and an output folder. Runs execute

* through joblib on the local cores (``workers``; default: every core), or
* on a Dask cluster when ``scheduler`` (an address such as ``tcp://10.0.0.5:8786``) is given.

Every finished run is written at once to ``<out>/runs/<key>.json`` (written to a temporary name and
renamed, so a file is either complete or absent). A restarted sweep reads the folder, skips the runs
already there and executes exactly the missing ones; the final table is assembled from the files in the
tasks' order, so an interrupted-and-resumed sweep ends with the same table as an uninterrupted one. The
folder's ``sweep.json`` manifest records the settings the stored results depend on; restarting with
different settings into the same folder is refused rather than mixing results.

The paper's sweeps (:func:`model_error_sweep`, Fig. 13; :func:`noise_sweep`, Fig. 14) repeat the Fig. 12
experiment (see :mod:`reflexarm.experiments.compensation`) with disturbance compensation, without and
with EFC, and score each run by the MSIE (20) against the compliant controller without compensation,
model errors or noise.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reflexarm.errors import ConfigError, DataError

__all__ = [
    "CONDITIONS",
    "DEFAULT_LEVELS",
    "SWEEP_KINDS",
    "PaperSweepContext",
    "PaperSweepResult",
    "SweepResult",
    "SweepTask",
    "load_runs",
    "paper_sweep",
    "paper_sweep_tasks",
    "parse_levels",
    "plot_sweep",
    "reference_trajectory",
    "run_paper_task",
    "run_sweep",
    "summarize_sweep",
    "trial_seeds",
]

RunFunction = Callable[["SweepTask", Any], dict[str, Any]]

#: Name of the manifest file in a sweep folder.
MANIFEST = "sweep.json"
RUNS_DIR = "runs"


@dataclass(frozen=True)
class SweepTask:
    """One run of a sweep.

    Attributes:
        kind: the sweep ("model-error", "noise", or any label of a user's sweep).
        level: the swept value (model-error level in percent, noise scale factor, ...).
        condition: the controller setting compared (e.g. "DC" = kappa_ext 0, "DC+EFC" = kappa_ext 1).
        trial: index of the random draw at this level, 0-based.
        seed: base seed of the sweep; with ``trial`` it fixes the random draws (:func:`trial_seeds`).
    """

    kind: str
    level: float
    condition: str
    trial: int
    seed: int = 0

    @property
    def key(self) -> str:
        """A file-name-safe unique identity, e.g. ``model-error_L10_DC+EFC_T003_S0``."""
        level = f"{self.level:g}".replace("-", "m")
        return f"{self.kind}_L{level}_{self.condition}_T{self.trial:03d}_S{self.seed}"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def trial_seeds(seed: int, trial: int) -> tuple[int, int]:
    """(model-error seed, noise seed) of a trial: independent streams, the same at every level and condition.

    Using the same draws for every level and for both controller settings (common random numbers) is
    what the paper does ("the model errors were the same in both plots") and makes differences between
    levels and settings reflect the settings, not the luck of the draw.
    """
    a, b = np.random.SeedSequence([int(seed), int(trial)]).generate_state(2)
    return int(a), int(b)


def parse_levels(spec: str | Sequence[float], *, name: str = "levels") -> list[float]:
    """Levels from ``"1:30"`` (inclusive range, step 1), ``"1:30:5"`` (step 5) or ``"1,2,5,10"``, or a sequence.

    Raises:
        ConfigError: unparsable text, empty, non-finite or negative levels (naming the value).
    """
    if isinstance(spec, str):
        text = spec.strip()
        try:
            parts = [float(p) for p in text.split(":" if ":" in text else ",") if p.strip()]
            if ":" in text and len(parts) not in (2, 3):
                raise ValueError(text)
        except ValueError as e:
            raise ConfigError(
                f"{name}: cannot parse {spec!r}; use a range 'start:stop[:step]' or a list '1,2,5'"
            ) from e
        if ":" in text:
            start, stop = parts[0], parts[1]
            step = parts[2] if len(parts) == 3 else 1.0
            if not step > 0:
                raise ConfigError(f"{name}: the step of {spec!r} must be positive")
            for v in (start, stop):
                if v < 0:
                    raise ConfigError(f"{name} must be non-negative; got {v:g}")
            count = int(math.floor((stop - start) / step + 1e-9)) + 1
            values = [start + k * step for k in range(max(count, 0))]
        else:
            values = parts
    else:
        try:
            values = [float(v) for v in spec]
        except (TypeError, ValueError) as e:
            raise ConfigError(f"{name} must be numbers; got {spec!r}") from e
    if not values:
        raise ConfigError(f"{name}: no levels in {spec!r}")
    for v in values:
        if not math.isfinite(v):
            raise ConfigError(f"{name} must be finite; got {v!r}")
        if v < 0:
            raise ConfigError(f"{name} must be non-negative; got {v:g}")
    return [round(v, 12) for v in values]


@dataclass
class SweepResult:
    """What :func:`run_sweep` returns.

    Attributes:
        table: one row per task, in the tasks' order: the task's fields, then the run function's results.
        ran: keys of the runs executed by this call (the others were found in the folder).
        skipped: keys found in the folder and not re-run.
        wall_s: wall time of this call [s].
        run_wall_s: wall time of each executed run, by key [s] (measured in the worker).
    """

    table: pd.DataFrame
    ran: list[str]
    skipped: list[str]
    wall_s: float
    run_wall_s: dict[str, float] = field(default_factory=dict)


def _check_workers(workers: object) -> int:
    if workers is None:
        return os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or int(workers) < 1:
        raise ConfigError(f"workers must be a positive integer; got {workers!r}")
    return int(workers)


def _prepare_folder(out: Path, manifest: dict[str, Any] | None) -> Path:
    out = Path(out)
    runs = out / RUNS_DIR
    runs.mkdir(parents=True, exist_ok=True)
    if manifest is None:
        return runs
    canonical = json.loads(json.dumps(manifest, default=str))
    path = out / MANIFEST
    if path.exists():
        try:
            stored = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise DataError(f"{path} is not valid JSON ({e}); delete it or use another output folder") from e
        if stored != canonical:
            diff = sorted(k for k in set(stored) | set(canonical) if stored.get(k) != canonical.get(k))
            raise ConfigError(
                f"{out} holds a sweep with other settings (differing: {', '.join(diff)}); resuming would mix "
                "results. Use another output folder or delete this one"
            )
    else:
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(canonical, indent=2, sort_keys=True))
        os.replace(tmp, path)
    return runs


def _write_run(runs: Path, task: SweepTask, result: dict[str, Any], wall_s: float) -> None:
    record = {"task": task.as_dict(), "result": result, "wall_s": wall_s}
    path = runs / f"{task.key}.json"
    tmp = runs / f".{task.key}.json.tmp"
    tmp.write_text(json.dumps(record, default=_json_default))
    os.replace(tmp, path)


def _json_default(x: object) -> object:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"run results must be JSON-serialisable scalars; got {type(x).__name__}")


def load_runs(out: str | os.PathLike[str], tasks: Sequence[SweepTask] | None = None) -> pd.DataFrame:
    """The stored runs of a sweep folder as a table (in the order of ``tasks`` if given, else by key).

    Tasks without a stored run are left out.
    """
    runs = Path(out) / RUNS_DIR
    records: dict[str, dict[str, Any]] = {}
    if runs.is_dir():
        for p in runs.glob("*.json"):
            try:
                records[p.stem] = json.loads(p.read_text())
            except json.JSONDecodeError as e:  # only possible if someone edited the file
                raise DataError(f"stored run {p} is not valid JSON ({e}); delete it to re-run it") from e
    keys = [t.key for t in tasks] if tasks is not None else sorted(records)
    rows = [{**records[k]["task"], **records[k]["result"]} for k in keys if k in records]
    return pd.DataFrame(rows)


def _call(run_fn: RunFunction, task: SweepTask, context: Any) -> tuple[SweepTask, dict[str, Any], float]:
    t0 = time.perf_counter()
    try:
        result = run_fn(task, context)
    except Exception as e:
        e.add_note(f"in sweep run {task.key}")
        raise
    if not isinstance(result, dict):
        raise DataError(f"the run function must return a dict of results; got {type(result).__name__}")
    return task, result, time.perf_counter() - t0


def _connect(scheduler: str, timeout: float) -> Any:
    from distributed import Client

    if not isinstance(scheduler, str) or not scheduler.strip():
        raise ConfigError(f"scheduler must be an address such as 'tcp://host:8786'; got {scheduler!r}")
    try:
        return Client(scheduler, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise ConfigError(
            f"cannot reach the Dask scheduler at {scheduler!r} within {timeout:g} s ({type(e).__name__}: {e}); "
            "start one (`dask scheduler` plus `dask worker ADDRESS`) or leave out --scheduler to run on the "
            "local cores"
        ) from e


def _iter_joblib(run_fn: RunFunction, todo: list[SweepTask], context: Any, workers: int) -> Iterable[tuple]:
    from joblib import Parallel, delayed

    if workers == 1:  # in-process, in order: no pickling, easiest to debug
        for task in todo:
            yield _call(run_fn, task, context)
        return
    parallel = Parallel(n_jobs=workers, return_as="generator_unordered", batch_size=1, pre_dispatch="2*n_jobs")
    yield from parallel(delayed(_call)(run_fn, task, context) for task in todo)


def _iter_dask(run_fn: RunFunction, todo: list[SweepTask], context: Any, scheduler: str, timeout: float) -> Iterable:
    from distributed import as_completed

    client = _connect(scheduler, timeout)
    futures = []
    try:
        ctx = client.scatter(context, broadcast=True) if context is not None else None
        futures = client.map(_call, [run_fn] * len(todo), todo, [ctx] * len(todo), pure=False)
        for fut in as_completed(futures, loop=client.loop):
            yield fut.result()
    finally:
        for f in futures:
            f.cancel()
        client.close()


def run_sweep(
    tasks: Sequence[SweepTask],
    run_fn: RunFunction,
    out: str | os.PathLike[str],
    *,
    context: Any = None,
    manifest: dict[str, Any] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    scheduler_timeout: float = 10.0,
    progress: bool = True,
    on_result: Callable[[SweepTask, dict[str, Any]], None] | None = None,
) -> SweepResult:
    """Run the tasks not yet stored in ``out``, store each as it finishes, return the full table.

    Args:
        tasks: the sweep's runs (keys must be unique).
        run_fn: ``run_fn(task, context) -> dict`` of JSON-serialisable scalars; must be picklable (a
            module-level function or a ``functools.partial`` of one) for parallel execution.
        out: output folder (created); holds ``sweep.json``, ``runs/*.json``, and afterwards
            ``results.csv`` and ``results.parquet``.
        context: one object shared by all runs (e.g. a reference trajectory); sent once per worker.
        manifest: settings the results depend on; stored on the first call, compared on a restart.
        workers: local processes (joblib); default every core; 1 runs in this process, in order.
        scheduler: address of a Dask scheduler; when given the runs go to its cluster instead.
        scheduler_timeout: how long to try to reach the scheduler [s].
        progress: show a tqdm progress bar.
        on_result: called in this process after each run is stored (e.g. for logging).

    Raises:
        ConfigError: duplicate tasks, bad ``workers``, unreachable scheduler, a folder holding a sweep with
            other settings.
        Exception: the first exception of a run function propagates (with a note naming the run); every run
            stored before it is kept, so the sweep resumes from there.
    """
    tasks = list(tasks)
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})
        raise ConfigError(f"duplicate sweep tasks: {', '.join(dup[:5])}")
    n_workers = _check_workers(workers)
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise ConfigError(f"scheduler must be an address such as 'tcp://host:8786'; got {scheduler!r}")
    t_start = time.perf_counter()
    out = Path(out)
    runs = _prepare_folder(out, manifest)
    done = {p.stem for p in runs.glob("*.json")}
    todo = [t for t in tasks if t.key not in done]
    skipped = [t.key for t in tasks if t.key in done]
    ran: list[str] = []
    run_wall: dict[str, float] = {}

    from tqdm.auto import tqdm

    bar = tqdm(total=len(tasks), initial=len(skipped), disable=not progress, desc=out.name or "sweep", unit="run")
    try:
        if todo:
            it = (
                _iter_dask(run_fn, todo, context, scheduler, scheduler_timeout)
                if scheduler is not None
                else _iter_joblib(run_fn, todo, context, min(n_workers, len(todo)))
            )
            try:
                for task, result, wall in it:
                    _write_run(runs, task, result, wall)
                    ran.append(task.key)
                    run_wall[task.key] = wall
                    bar.update(1)
                    if on_result is not None:
                        on_result(task, result)
            except Exception as e:
                e.add_note(
                    f"sweep interrupted after {len(ran)} new runs; {len(skipped) + len(ran)} of {len(tasks)} are "
                    f"stored in {runs} and will not be re-run"
                )
                raise
    finally:
        bar.close()
    table = load_runs(out, tasks)
    table.to_csv(out / "results.csv", index=False)
    table.to_parquet(out / "results.parquet", index=False)
    return SweepResult(table, ran, skipped, time.perf_counter() - t_start, run_wall)


# ------------------------------------------------------------------------------------------------------
# The paper's sweeps: Fig. 13 (model errors) and Fig. 14 (sensor noise)
# ------------------------------------------------------------------------------------------------------

#: The two controller settings compared in Figs. 13-14: disturbance compensation without / with EFC.
CONDITIONS: dict[str, int] = {"DC": 0, "DC+EFC": 1}
SWEEP_KINDS = ("model-error", "noise")
#: Default level grids: 1 % to 30 % model errors (Fig. 13), noise scale 1 to 30 (Fig. 14).
DEFAULT_LEVELS = {"model-error": [float(v) for v in range(1, 31)], "noise": [float(v) for v in range(1, 31)]}
LEVEL_UNITS = {"model-error": "max. model error [%]", "noise": "noise scale factor [-]"}


@dataclass(frozen=True)
class PaperSweepContext:
    """What every run of a paper sweep shares: the setup and the reference trajectory q_ref of (20)."""

    setup: Any  # CompensationSetup (typed loosely to keep this module importable without the sim)
    t_ref: np.ndarray
    q_ref: np.ndarray


def paper_sweep_tasks(kind: str, levels: Sequence[float] | str, trials: int, seed: int = 0) -> list[SweepTask]:
    """The runs of a Fig. 13 / Fig. 14 sweep: every level x condition x trial.

    Raises:
        ConfigError: unknown kind, bad level (negative; >= 100 % model error), trials < 1.
    """
    if kind not in SWEEP_KINDS:
        raise ConfigError(f"unknown sweep {kind!r}; choose one of: {', '.join(SWEEP_KINDS)}")
    lv = parse_levels(levels)
    if kind == "model-error":
        bad = [v for v in lv if v >= 100.0]
        if bad:
            raise ConfigError(f"model-error levels are percentages below 100; got {bad[0]:g}")
    if isinstance(trials, bool) or not isinstance(trials, (int, np.integer)) or trials < 1:
        raise ConfigError(f"trials must be a positive integer; got {trials!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer; got {seed!r}")
    return [SweepTask(kind, v, c, k, int(seed)) for v in lv for c in CONDITIONS for k in range(int(trials))]


def run_paper_task(task: SweepTask, context: PaperSweepContext) -> dict[str, Any]:
    """One run of Fig. 13/14: the Fig. 12 experiment with DC, kappa_ext by condition, scored by MSIE (20).

    The model-error draw and the noise sequence come from :func:`trial_seeds` (the same for every level
    and both conditions). A diverged simulation is a result (``status = "diverged"``, MSIE NaN).
    """
    from reflexarm.errors import SimulationError
    from reflexarm.experiments import compensation as comp
    from reflexarm.experiments.metrics import msie_per_joint, window_mean

    setup = context.setup
    model_seed, noise_seed = trial_seeds(task.seed, task.trial)
    if task.kind == "model-error":
        model_error, noise_scale = task.level / 100.0, setup.noise_scale
    elif task.kind == "noise":
        model_error, noise_scale = setup.model_error, task.level
    else:
        raise ConfigError(f"unknown sweep {task.kind!r}; choose one of: {', '.join(SWEEP_KINDS)}")
    try:
        trace = comp.run_case(
            setup,
            1,
            CONDITIONS[task.condition],
            model_error=model_error,
            noise_scale=noise_scale,
            model_seed=model_seed,
            noise_seed=noise_seed,
        )
    except SimulationError as e:
        return {"msie": float("nan"), "status": "diverged", "error": str(e)}
    if trace.q.shape != context.q_ref.shape:
        raise DataError(f"run {task.key} has {trace.q.shape} samples, the reference {context.q_ref.shape}")
    load = setup.load_window
    per_joint = msie_per_joint(trace.t, trace.q, context.q_ref)
    return {
        "msie": float(per_joint.mean()),
        "status": "ok",
        **{f"msie_j{i + 1}": float(v) for i, v in enumerate(per_joint)},
        "residual1_load_Nm": float(window_mean(trace.t, trace.residual[:, 0], *load)),
        "q1_load_rad": float(window_mean(trace.t, trace.q[:, 0], *load)),
        "max_abs_residual_Nm": float(np.abs(trace.residual).max()),
    }


def summarize_sweep(table: pd.DataFrame) -> pd.DataFrame:
    """Per level and condition: MSIE mean/min/max over the trials, normalised by the figure's maximum.

    ``||MSIE|| = MSIE / max(MSIE)`` with the maximum over every run of the figure (both conditions, all
    levels), as the paper normalises Figs. 13 and 14 separately. ``ratio_dc_to_efc`` is the mean MSIE
    without EFC over the mean with EFC at the same level.
    """
    if table.empty:
        raise DataError("no runs to summarise")
    ok = table[table["status"] == "ok"]
    peak = float(ok["msie"].max())
    g = ok.groupby(["level", "condition"])["msie"]
    out = g.agg(n="count", msie_mean="mean", msie_min="min", msie_max="max").reset_index()
    for c in ("mean", "min", "max"):
        out[f"norm_{c}"] = out[f"msie_{c}"] / peak
    diverged = table[table["status"] != "ok"].groupby(["level", "condition"]).size()
    out["diverged"] = [int(diverged.get((lv, c), 0)) for lv, c in zip(out["level"], out["condition"], strict=True)]
    means = out.pivot(index="level", columns="condition", values="msie_mean")
    if set(CONDITIONS) <= set(means.columns):
        ratio = means["DC"] / means["DC+EFC"]
        out["ratio_dc_to_efc"] = out["level"].map(ratio)
    return out.sort_values(["condition", "level"]).reset_index(drop=True)


def plot_sweep(summary: pd.DataFrame, kind: str, path: str | os.PathLike[str]) -> Path:
    """Figs. 13/14: normalised MSIE over the level, top without EFC (kappa_ext = 0), bottom with EFC."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True, sharey=True)
    for ax, (cond, kext) in zip(axes, CONDITIONS.items(), strict=True):
        s = summary[summary["condition"] == cond].sort_values("level")
        ax.fill_between(s["level"], s["norm_min"], s["norm_max"], color="C0", alpha=0.25, lw=0, label="min-max")
        ax.plot(s["level"], s["norm_mean"], "o-", color="C0", ms=3, label="mean")
        ax.set_yscale("log")
        ax.set_ylabel("||MSIE|| [-]")
        ax.set_title(f"DC, $\\kappa_{{ext}} = {kext}$" + (" (EFC)" if kext else " (no EFC)"), fontsize=10)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel(LEVEL_UNITS.get(kind, "level"))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=120)
    return p


@dataclass
class PaperSweepResult:
    """What :func:`paper_sweep` returns: the run table, the per-level summary and the output files."""

    sweep: SweepResult
    summary: pd.DataFrame
    figure: Path
    files: dict[str, Path]


def reference_trajectory(setup: Any, out: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """q_ref of (20) for ``setup``, cached in ``<out>/reference.npz`` (computed once per sweep folder)."""
    from reflexarm.experiments import compensation as comp

    path = Path(out) / "reference.npz"
    if path.exists():
        with np.load(path) as z:
            return z["t"].copy(), z["q"].copy()
    tr = comp.reference_run(setup)
    Path(out).mkdir(parents=True, exist_ok=True)
    tmp = Path(out) / ".reference.tmp.npz"
    np.savez(tmp, t=tr.t, q=tr.q)
    os.replace(tmp, path)
    return tr.t, tr.q


def paper_sweep(
    kind: str,
    out: str | os.PathLike[str],
    *,
    levels: Sequence[float] | str | None = None,
    trials: int = 10,
    seed: int = 0,
    setup: Any = None,
    workers: int | None = None,
    scheduler: str | None = None,
    scheduler_timeout: float = 10.0,
    progress: bool = True,
) -> PaperSweepResult:
    """Fig. 13 (``kind="model-error"``, levels in percent) or Fig. 14 (``kind="noise"``, scale factors).

    Writes into ``out``: ``runs/*.json`` (one per run, as they finish), ``reference.npz``,
    ``results.csv``/``results.parquet`` (one row per run), ``summary.csv`` (per level and condition)
    and ``fig13_model_error.png`` / ``fig14_noise.png``. Resumes an interrupted sweep in the same folder.
    """
    from reflexarm.experiments.compensation import CompensationSetup

    setup = setup or CompensationSetup()
    tasks = paper_sweep_tasks(kind, DEFAULT_LEVELS[kind] if levels is None else levels, trials, seed)
    n_workers = _check_workers(workers)
    out = Path(out)
    manifest = {"experiment": f"paper-sweep/{kind}", "format": 1, "seed": int(seed), "setup": setup.as_dict()}
    _prepare_folder(out, manifest)  # refuse a folder with other settings before the reference run
    if scheduler is not None:  # and an unreachable scheduler
        _connect(scheduler, scheduler_timeout).close()
    t_ref, q_ref = reference_trajectory(setup, out)
    context = PaperSweepContext(setup, t_ref, q_ref)
    res = run_sweep(
        tasks,
        run_paper_task,
        out,
        context=context,
        manifest=manifest,
        workers=n_workers,
        scheduler=scheduler,
        scheduler_timeout=scheduler_timeout,
        progress=progress,
    )
    summary = summarize_sweep(res.table)
    summary.to_csv(out / "summary.csv", index=False)
    fig = plot_sweep(summary, kind, out / ("fig13_model_error.png" if kind == "model-error" else "fig14_noise.png"))
    files = {
        "results_csv": out / "results.csv",
        "results_parquet": out / "results.parquet",
        "summary_csv": out / "summary.csv",
        "figure": fig,
    }
    return PaperSweepResult(res, summary, fig, files)
