"""Figs. 13 and 14: robustness of DC with and without EFC against model errors and sensor noise.

Each run repeats the Fig. 12 experiment (:mod:`reflexarm.experiments.compensation`: controller (2) with
k_o = 10 1/s, k_i = 150 Nm/rad, d_xi = 0.3, 30 Nm cut-off, kappa_f = 1, 50 N step 0.5-3.5 s) with
disturbance compensation (kappa_eps = 1), without EFC ("DC", kappa_ext = 0) and with it ("DC+EFC",
kappa_ext = 1), and scores it by the MSIE (20) against q_ref: "the compliant behavior of the controller
without disturbance compensation and without model errors or measurement noise"
(:func:`~reflexarm.experiments.compensation.reference_run`). Both conditions of a trial share the
model-error draw and the noise sequence at every level (:func:`~reflexarm.experiments.sweeps.trial_seeds`).

Besides the MSIE every run records what explains it:

* the achieved model error of its controller model (relative error of g(q) and M(q), median over
  random states, :func:`reflexarm.robots.perturbation.measure_model_error`), printed per level;
* joint 1's residual under the load: its mean, its standard deviation, the fraction of ticks beyond the
  cut-off and the mean of the *compensated* (cut-off) residual, and the residual noise predicted from the
  velocity noise, ``k_o |M_hat_1,:(q)| a_dq s / sqrt(3)`` (the momentum ``M_hat(q) dq`` enters the residual
  (4) unfiltered, so uniform velocity noise of half-width ``a_dq s`` reaches it times ``k_o``). These show
  the mechanism of Fig. 14's crossover: the cut-off removes part of DC's compensation of the load only when
  the noisy residual reaches 30 Nm.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reflexarm.errors import ConfigError, DataError, SimulationError
from reflexarm.experiments.compensation import (
    CompensationSetup,
    controller_model,
    held_posture,
    reference_run,
    run_case,
    true_robot,
)
from reflexarm.experiments.metrics import msie_per_joint, window_mean
from reflexarm.experiments.sweeps import (
    SweepResult,
    SweepTask,
    check_workers,
    connect_scheduler,
    parse_levels,
    prepare_folder,
    run_sweep,
    trial_seeds,
)
from reflexarm.robots.perturbation import measure_model_error

__all__ = [
    "CONDITIONS",
    "DEFAULT_LEVELS",
    "SWEEP_KINDS",
    "PaperSweepContext",
    "PaperSweepResult",
    "paper_sweep",
    "paper_sweep_tasks",
    "predicted_residual_noise",
    "reference_trajectory",
    "run_paper_task",
    "summarize_sweep",
]

#: The two controller settings compared in Figs. 13-14: disturbance compensation without / with EFC.
CONDITIONS: dict[str, int] = {"DC": 0, "DC+EFC": 1}
SWEEP_KINDS = ("model-error", "noise")
#: Default level grids: 1 % to 30 % model errors (Fig. 13), noise scale 1 to 30 (Fig. 14).
DEFAULT_LEVELS = {"model-error": [float(v) for v in range(1, 31)], "noise": [float(v) for v in range(1, 31)]}
LEVEL_UNITS = {"model-error": "max. model error [%]", "noise": "noise scale factor [-]"}
#: Random joint states over which the achieved model error is measured (seeded, the same for every run).
ERROR_STATES = 100


@dataclass(frozen=True)
class PaperSweepContext:
    """What every run of a paper sweep shares: the setup and the reference trajectory q_ref of (20)."""

    setup: CompensationSetup
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


def predicted_residual_noise(setup: CompensationSetup, noise_scale: float, joint: int = 0) -> float:
    """Standard deviation of the residual's noise from the velocity noise alone [Nm].

    ``k_o |M_hat_i,:(q)|_2 a s / sqrt(3)``: (4) contains ``K_o M_hat(q) dq`` unfiltered; the velocity noise
    is uniform with half-width ``a s`` per component (variance ``(a s)^2 / 3``), independent over joints.
    Evaluated with the true model at the held posture (the model error changes it by ~ the level).
    """
    robot = true_robot(setup)
    dq_level = setup.sensor_noise(noise_scale).dq
    row = robot.compute_mass_matrix(held_posture(setup, robot))[joint]
    return float(setup.observer_gain * np.linalg.norm(row) * dq_level / math.sqrt(3.0))


def _achieved_error(setup: CompensationSetup, model_error: float, model_seed: int) -> dict[str, float]:
    robot = true_robot(setup)
    model = controller_model(setup, model_error, model_seed)
    e = measure_model_error(robot, model, n_states=ERROR_STATES, seed=0)
    return {
        "g_error_median": e.gravity_median,
        "g_error_max": e.gravity_max,
        "M_error_median": e.mass_matrix_median,
        "M_error_max": e.mass_matrix_max,
    }


def run_paper_task(task: SweepTask, context: PaperSweepContext) -> dict[str, Any]:
    """One run of Fig. 13/14: the Fig. 12 experiment with DC, kappa_ext by condition, scored by MSIE (20).

    The model-error draw and the noise sequence come from :func:`trial_seeds` (the same for every level
    and both conditions). A diverged simulation is a result (``status = "diverged"``, MSIE NaN).
    """
    setup = context.setup
    model_seed, noise_seed = trial_seeds(task.seed, task.trial)
    if task.kind == "model-error":
        model_error, noise_scale = task.level / 100.0, setup.noise_scale
    elif task.kind == "noise":
        model_error, noise_scale = (0.0 if setup.model_file else setup.model_error), task.level
    else:
        raise ConfigError(f"unknown sweep {task.kind!r}; choose one of: {', '.join(SWEEP_KINDS)}")
    try:
        trace = run_case(
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
    lo, hi = setup.load_window
    per_joint = msie_per_joint(trace.t, trace.q, context.q_ref)
    in_load = (trace.t >= lo) & (trace.t <= hi)
    r1 = trace.residual[in_load, 0]
    limit = setup.residual_limit
    return {
        "msie": float(per_joint.mean()),
        "status": "ok",
        "loop": str(trace.meta.get("loop", "python")),  # compiled (C++) or python: the same numbers either way
        **{f"msie_j{i + 1}": float(v) for i, v in enumerate(per_joint)},
        "residual1_load_Nm": float(window_mean(trace.t, trace.residual[:, 0], lo, hi)),
        "residual1_load_std_Nm": float(r1.std()),
        "residual1_clip_fraction": float(np.mean(np.abs(r1) > limit)),
        "compensated1_load_Nm": float(np.clip(r1, -limit, limit).mean()),
        "residual1_noise_pred_Nm": predicted_residual_noise(setup, noise_scale),
        "tau_ext1_load_Nm": float(window_mean(trace.t, trace.tau_ext[:, 0], lo, hi)),
        "q1_load_rad": float(window_mean(trace.t, trace.q[:, 0], lo, hi)),
        "max_abs_residual_Nm": float(np.abs(trace.residual).max()),
        **_achieved_error(setup, model_error, model_seed),
    }


#: Columns of a run averaged per level and condition by :func:`summarize_sweep` (besides the MSIE).
MEAN_COLUMNS = (
    "g_error_median",
    "M_error_median",
    "g_error_max",
    "M_error_max",
    "residual1_load_Nm",
    "residual1_load_std_Nm",
    "residual1_clip_fraction",
    "compensated1_load_Nm",
    "residual1_noise_pred_Nm",
    "tau_ext1_load_Nm",
)


def summarize_sweep(table: pd.DataFrame) -> pd.DataFrame:
    """Per level and condition: MSIE mean/min/max over the trials, normalised by the figure's maximum.

    ``||MSIE|| = MSIE / max(MSIE)`` with the maximum over every run of the figure (both conditions, all
    levels), as the paper normalises Figs. 13 and 14 separately. ``ratio_dc_to_efc`` is the mean MSIE
    without EFC over the mean with EFC at the same level. The columns of :data:`MEAN_COLUMNS` present in
    the table are averaged over the trials.
    """
    if table.empty:
        raise DataError("no runs to summarise")
    ok = table[table["status"] == "ok"]
    if ok.empty:
        raise DataError(f"every one of the {len(table)} runs diverged; nothing to summarise")
    peak = float(ok["msie"].max())
    g = ok.groupby(["level", "condition"])
    out = g["msie"].agg(n="count", msie_mean="mean", msie_min="min", msie_max="max").reset_index()
    extra = [c for c in MEAN_COLUMNS if c in ok.columns]
    if extra:
        out = out.merge(g[extra].mean().reset_index(), on=["level", "condition"])
    for c in ("mean", "min", "max"):
        out[f"norm_{c}"] = out[f"msie_{c}"] / peak
    diverged = table[table["status"] != "ok"].groupby(["level", "condition"]).size()
    out["diverged"] = [int(diverged.get((lv, c), 0)) for lv, c in zip(out["level"], out["condition"], strict=True)]
    means = out.pivot(index="level", columns="condition", values="msie_mean")
    if set(CONDITIONS) <= set(means.columns):
        ratio = means["DC"] / means["DC+EFC"]
        out["ratio_dc_to_efc"] = out["level"].map(ratio)
    return out.sort_values(["condition", "level"]).reset_index(drop=True)


@dataclass
class PaperSweepResult:
    """What :func:`paper_sweep` returns: the run table, the per-level summary and the output files."""

    sweep: SweepResult
    summary: pd.DataFrame
    figure: Path
    files: dict[str, Path]


def reference_trajectory(setup: CompensationSetup, out: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """q_ref of (20) for ``setup``, cached in ``<out>/reference.npz`` (computed once per sweep folder)."""
    path = Path(out) / "reference.npz"
    if path.exists():
        with np.load(path) as z:
            return z["t"].copy(), z["q"].copy()
    tr = reference_run(setup)
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
    setup: CompensationSetup | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    scheduler_timeout: float = 10.0,
    progress: bool = True,
) -> PaperSweepResult:
    """Fig. 13 (``kind="model-error"``, levels in percent) or Fig. 14 (``kind="noise"``, scale factors).

    Writes into ``out``: ``runs/*.json`` (one per run, as they finish), ``reference.npz``,
    ``results.csv``/``results.parquet`` (one row per run), ``summary.csv`` (per level and condition)
    and ``fig13_model_error.png`` / ``fig14_noise.png``. Resumes an interrupted sweep in the same folder.

    Raises:
        ConfigError: a model-error sweep on a setup with an identified ``model_file`` (its level would
            mean nothing), and the errors of :func:`paper_sweep_tasks` and :func:`run_sweep`.
    """
    from reflexarm.experiments.plots import plot_sweep

    setup = setup or CompensationSetup()
    if kind == "model-error" and setup.model_file is not None:
        raise ConfigError(
            f"a model-error sweep perturbs the true model at each level; got the identified model "
            f"{setup.model_file!r} as well (use it with the noise sweep or drop it)"
        )
    tasks = paper_sweep_tasks(kind, DEFAULT_LEVELS[kind] if levels is None else levels, trials, seed)
    n_workers = check_workers(workers)
    out = Path(out)
    manifest = {"experiment": f"paper-sweep/{kind}", "format": 2, "seed": int(seed), "setup": setup.as_dict()}
    prepare_folder(out, manifest)  # refuse a folder with other settings before the reference run
    if scheduler is not None:  # and an unreachable scheduler
        connect_scheduler(scheduler, scheduler_timeout).close()
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
    name = "fig13_model_error.png" if kind == "model-error" else "fig14_noise.png"
    fig = plot_sweep(summary, kind, out / name, residual_limit=setup.residual_limit)
    files = {
        "results_csv": out / "results.csv",
        "results_parquet": out / "results.parquet",
        "summary_csv": out / "summary.csv",
        "figure": fig,
    }
    return PaperSweepResult(res, summary, fig, files)
