"""Sweeps at scale: many independent closed-loop runs, in parallel, resumable.

The machinery (:func:`run_sweep`) is generic: a list of :class:`SweepTask`, a picklable run function
``run_fn(task, context) -> dict`` and an output folder. Runs execute

* on the local cores (``workers`` spawned processes, default every core; each is killed by the kernel when the
  sweep's process dies, even by ``kill -9``: no orphaned workers), or
* on a Dask cluster when ``scheduler`` (an address such as ``tcp://10.0.0.5:8786``) is given.

Every finished run is written at once to ``<out>/runs/<key>.json`` (written to a temporary name and
renamed, so a file is either complete or absent). A restarted sweep reads the folder, skips the runs
already there and executes exactly the missing ones; the final table is assembled from the files in the
tasks' order, so an interrupted-and-resumed sweep ends with the same table as an uninterrupted one. The
folder's ``sweep.json`` manifest records the settings the stored results depend on; restarting with
different settings into the same folder is refused rather than mixing results.

The paper's sweeps (Figs. 13 and 14) are built on this machinery in :mod:`reflexarm.experiments.robustness`.
This module imports nothing of the experiments (they import it).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reflexarm.errors import ConfigError, DataError

__all__ = [
    "SweepResult",
    "SweepTask",
    "check_workers",
    "connect_scheduler",
    "load_runs",
    "parse_levels",
    "prepare_folder",
    "run_sweep",
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


def check_workers(workers: object) -> int:
    """The number of local worker processes: ``workers``, or every core for None.

    Raises:
        ConfigError: not a positive integer (naming the value).
    """
    if workers is None:
        return os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or int(workers) < 1:
        raise ConfigError(f"workers must be a positive integer; got {workers!r}")
    return int(workers)


def prepare_folder(out: Path, manifest: dict[str, Any] | None) -> Path:
    """Create ``out/runs``; store ``manifest`` on the first call, refuse a folder holding other settings.

    Raises:
        DataError: an unreadable manifest. ConfigError: a manifest with other settings.
    """
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


def connect_scheduler(scheduler: str, timeout: float) -> Any:
    """A Dask client of ``scheduler``; ConfigError naming the address if it cannot be reached."""
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


def _die_with_parent(parent: int) -> None:
    """Worker initializer: the kernel kills this worker when the sweep's process dies, even by SIGKILL (Linux
    PR_SET_PDEATHSIG; elsewhere the pool's own shutdown is all there is)."""
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL))  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the line above took effect
        os._exit(1)


def _iter_local(run_fn: RunFunction, todo: list[SweepTask], context: Any, workers: int) -> Iterable[tuple]:
    """The runs on ``workers`` local processes (spawned, each dies with this process), at most two queued per
    worker, results as they finish."""
    if workers == 1:  # in-process, in order: no pickling, easiest to debug
        for task in todo:
            yield _call(run_fn, task, context)
        return
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

    pool = ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn"), initializer=_die_with_parent,
        initargs=(os.getpid(),),
    )  # fmt: skip
    pending: set[Future] = set()
    queue = iter(todo)
    try:
        while True:
            for task in queue:
                pending.add(pool.submit(_call, run_fn, task, context))
                if len(pending) >= 2 * workers:
                    break
            if not pending:
                return
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                yield fut.result()
    finally:
        pool.shutdown(wait=not pending, cancel_futures=True)


def _iter_dask(run_fn: RunFunction, todo: list[SweepTask], context: Any, scheduler: str, timeout: float) -> Iterable:
    from distributed import as_completed

    client = connect_scheduler(scheduler, timeout)
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


@contextmanager
def _sweep_bar(total: int, initial: int, progress: bool, name: str) -> Iterator[Any]:
    """The sweep's progress bar (runs), closed whatever happens."""
    from tqdm.auto import tqdm

    from reflexarm._progress import show_progress

    bar = tqdm(total=total, initial=initial, disable=not show_progress(progress), desc=name, unit="run")
    try:
        yield bar
    finally:
        bar.close()


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
        workers: local processes; default every core; 1 runs in this process, in order.
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
    n_workers = check_workers(workers)
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise ConfigError(f"scheduler must be an address such as 'tcp://host:8786'; got {scheduler!r}")
    t_start = time.perf_counter()
    out = Path(out)
    runs = prepare_folder(out, manifest)
    done = {p.stem for p in runs.glob("*.json")}
    todo = [t for t in tasks if t.key not in done]
    skipped = [t.key for t in tasks if t.key in done]
    ran: list[str] = []
    run_wall: dict[str, float] = {}
    if todo:
        it = (
            _iter_dask(run_fn, todo, context, scheduler, scheduler_timeout)
            if scheduler is not None
            else _iter_local(run_fn, todo, context, min(n_workers, len(todo)))
        )
        with _sweep_bar(len(tasks), len(skipped), progress, out.name or "sweep") as bar:
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
    table = load_runs(out, tasks)
    table.to_csv(out / "results.csv", index=False)
    table.to_parquet(out / "results.parquet", index=False)
    return SweepResult(table, ran, skipped, time.perf_counter() - t_start, run_wall)
