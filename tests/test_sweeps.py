"""Sweep machinery: parallel execution (joblib, Dask), store-as-you-go, exact resume, clear errors.

The run function here is cheap and deterministic, so the machinery is tested on its own; the paper's
sweeps (Figs. 13-14) are tested in ``test_sweeps_paper.py``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from reflexarm.errors import ConfigError
from reflexarm.experiments.sweeps import SweepTask, load_runs, parse_levels, run_sweep, trial_seeds

HERE = Path(__file__).resolve().parent


def cheap_run(task, context):
    """Deterministic in (task, context): a random draw from the trial's seeds, like a real run."""
    model_seed, noise_seed = trial_seeds(task.seed, task.trial)
    x = np.random.default_rng(model_seed).uniform(-1, 1) * task.level + context["offset"]
    return {"value": float(x), "noise_draw": float(np.random.default_rng(noise_seed).uniform()), "pid": 0}


class RecordingRun:
    """cheap_run that leaves a marker file per call (works across processes) and may fail on some keys."""

    def __init__(self, marker_dir, fail_on=(), delay=0.0):
        self.marker_dir = str(marker_dir)
        self.fail_on = set(fail_on)
        self.delay = delay

    def __call__(self, task, context):
        if task.key in self.fail_on:
            raise RuntimeError(f"simulated crash in {task.key}")
        time.sleep(self.delay)
        Path(self.marker_dir, task.key).touch()
        return cheap_run(task, context)


def tasks(levels=(1.0, 5.0, 10.0), trials=4, seed=7):
    return [SweepTask("toy", lv, cond, k, seed) for lv in levels for cond in ("DC", "DC+EFC") for k in range(trials)]


CTX = {"offset": 0.5}


def markers(d):
    return sorted(p.name for p in Path(d).iterdir())


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    res = run_sweep(tasks(), cheap_run, out, context=CTX, manifest={"seed": 7}, workers=1, progress=False)
    return res.table


def test_table_has_one_row_per_task_in_task_order(uninterrupted, tmp_path):
    tk = tasks()
    assert list(uninterrupted["condition"]) == [t.condition for t in tk]
    assert list(uninterrupted["trial"]) == [t.trial for t in tk]
    assert {"kind", "level", "condition", "trial", "seed", "value", "noise_draw"} <= set(uninterrupted.columns)


def test_parallel_joblib_gives_the_same_table(uninterrupted, tmp_path):
    res = run_sweep(tasks(), cheap_run, tmp_path, context=CTX, manifest={"seed": 7}, workers=2, progress=False)
    pd.testing.assert_frame_equal(res.table, uninterrupted)
    assert sorted(res.ran) == sorted(t.key for t in tasks()) and res.skipped == []
    # outputs: CSV and Parquet of the same table, one JSON per run
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "results.parquet"), uninterrupted)
    assert len(list((tmp_path / "runs").glob("*.json"))) == len(tasks())
    assert pd.read_csv(tmp_path / "results.csv").shape == uninterrupted.shape


def test_crash_midway_then_resume_runs_exactly_the_missing(uninterrupted, tmp_path):
    tk = tasks()
    out, m1, m2 = tmp_path / "out", tmp_path / "m1", tmp_path / "m2"
    m1.mkdir()
    m2.mkdir()
    crash_at = 9
    with pytest.raises(RuntimeError, match=f"simulated crash in {tk[crash_at].key}") as e:
        run_sweep(
            tk,
            RecordingRun(m1, fail_on={tk[crash_at].key}),
            out,
            context=CTX,
            manifest={"seed": 7},
            workers=1,
            progress=False,
        )
    assert any("9 of 24 are stored" in note for note in e.value.__notes__)
    stored = set(load_runs(out, tk)["trial"].index)
    assert len(stored) == crash_at  # in-process, in order: exactly the runs before the crash
    res = run_sweep(tk, RecordingRun(m2), out, context=CTX, manifest={"seed": 7}, workers=1, progress=False)
    assert markers(m2) == sorted(t.key for t in tk[crash_at:])  # exactly the missing runs, each once
    assert sorted(res.skipped) == sorted(t.key for t in tk[:crash_at])
    pd.testing.assert_frame_equal(res.table, uninterrupted)


@pytest.mark.filterwarnings("ignore:.*tasks have been successfully executed:UserWarning")
def test_interrupt_from_callback_with_two_workers_then_resume(uninterrupted, tmp_path):
    tk = tasks()
    out, m1, m2 = tmp_path / "out", tmp_path / "m1", tmp_path / "m2"
    m1.mkdir()
    m2.mkdir()
    seen = []

    def stop_after_5(task, result):
        seen.append(task.key)
        if len(seen) == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(
            tk,
            RecordingRun(m1, delay=0.02),
            out,
            context=CTX,
            manifest={"seed": 7},
            workers=2,
            progress=False,
            on_result=stop_after_5,
        )
    stored = {p.stem for p in (out / "runs").glob("*.json")}
    assert stored == set(seen)  # every run the parent received is on disk, nothing else
    res = run_sweep(tk, RecordingRun(m2), out, context=CTX, manifest={"seed": 7}, workers=2, progress=False)
    assert markers(m2) == sorted(set(t.key for t in tk) - stored)
    pd.testing.assert_frame_equal(res.table, uninterrupted)


KILL_SCRIPT = textwrap.dedent(
    """
    import sys, time
    sys.path.insert(0, {here!r})
    from test_sweeps import RecordingRun, tasks, CTX
    from reflexarm.experiments.sweeps import run_sweep
    run_sweep(tasks(), RecordingRun({markers!r}, delay=0.15), {out!r}, context=CTX, manifest={{"seed": 7}},
              workers=1, progress=False)
    """
)


def test_killed_process_then_resume(uninterrupted, tmp_path):
    # a real kill (SIGKILL, no clean-up) of a sweep running in another process, then a restart here
    out, m1, m2 = tmp_path / "out", tmp_path / "m1", tmp_path / "m2"
    m1.mkdir()
    m2.mkdir()
    script = KILL_SCRIPT.format(here=str(HERE), markers=str(m1), out=str(out))
    proc = subprocess.Popen([sys.executable, "-c", script], env={**os.environ, "PYTHONPATH": str(HERE)})
    try:
        deadline = time.time() + 60
        while time.time() < deadline and len(list(out.glob("runs/*.json"))) < 6:
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    stored = {p.stem for p in (out / "runs").glob("*.json")}
    assert 6 <= len(stored) < len(tasks())
    # a run that started but was killed before its file was renamed into place left at most a temp file
    assert all(p.name.startswith(".") for p in (out / "runs").iterdir() if p.suffix != ".json")
    res = run_sweep(tasks(), RecordingRun(m2), out, context=CTX, manifest={"seed": 7}, workers=1, progress=False)
    assert markers(m2) == sorted({t.key for t in tasks()} - stored)
    pd.testing.assert_frame_equal(res.table, uninterrupted)


def test_dask_local_cluster_gives_the_same_table(uninterrupted, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        res = run_sweep(
            tasks(),
            cheap_run,
            tmp_path,
            context=CTX,
            manifest={"seed": 7},
            scheduler=cluster.scheduler_address,
            progress=False,
        )
    pd.testing.assert_frame_equal(res.table, uninterrupted)
    assert len(res.ran) == len(tasks())


def test_unreachable_scheduler_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError) as e:
        run_sweep(
            tasks(trials=1),
            cheap_run,
            tmp_path,
            context=CTX,
            scheduler="tcp://127.0.0.1:9",
            scheduler_timeout=1.0,
            progress=False,
        )
    msg = str(e.value)
    assert "cannot reach the Dask scheduler at 'tcp://127.0.0.1:9' within 1 s" in msg
    assert "leave out --scheduler" in msg


def test_other_settings_in_the_same_folder_are_refused(tmp_path):
    run_sweep(
        tasks(trials=1), cheap_run, tmp_path, context=CTX, manifest={"seed": 7, "k": 150}, workers=1, progress=False
    )
    with pytest.raises(ConfigError, match="holds a sweep with other settings \\(differing: k\\)"):
        run_sweep(
            tasks(trials=1), cheap_run, tmp_path, context=CTX, manifest={"seed": 7, "k": 300}, workers=1, progress=False
        )


def test_extending_a_sweep_runs_only_the_new_tasks(tmp_path):
    run_sweep(tasks(trials=2), cheap_run, tmp_path, context=CTX, manifest={"seed": 7}, workers=1, progress=False)
    res = run_sweep(tasks(trials=3), cheap_run, tmp_path, context=CTX, manifest={"seed": 7}, workers=1, progress=False)
    assert sorted(res.ran) == sorted(t.key for t in tasks(trials=3) if t.trial == 2)


@pytest.mark.parametrize(
    "spec, expected",
    [("1:5", [1, 2, 3, 4, 5]), ("1:30:10", [1, 11, 21]), ("1,2, 5", [1, 2, 5]), ([0.5, 2], [0.5, 2.0])],
)
def test_parse_levels(spec, expected):
    assert parse_levels(spec) == expected


@pytest.mark.parametrize(
    "spec, message",
    [
        ("-5,1", "levels must be non-negative; got -5"),
        ("1:x", "levels: cannot parse '1:x'; use a range 'start:stop[:step]' or a list '1,2,5'"),
        ("", "levels: no levels in ''"),
        ("1:5:0", "levels: the step of '1:5:0' must be positive"),
        ("nan", "levels must be finite"),
    ],
)
def test_bad_levels_are_named(spec, message):
    with pytest.raises(ConfigError) as e:
        parse_levels(spec)
    assert message in str(e.value)


@pytest.mark.parametrize(
    "workers, message",
    [(0, "workers must be a positive integer; got 0"), (1.5, "workers must be a positive integer; got 1.5")],
)
def test_bad_workers(tmp_path, workers, message):
    with pytest.raises(ConfigError, match=message):
        run_sweep(tasks(trials=1), cheap_run, tmp_path, context=CTX, workers=workers, progress=False)


def test_duplicate_tasks_are_refused(tmp_path):
    t = SweepTask("toy", 1.0, "DC", 0)
    with pytest.raises(ConfigError, match="duplicate sweep tasks: toy_L1_DC_T000_S0"):
        run_sweep([t, t], cheap_run, tmp_path, context=CTX, progress=False)


def test_trial_seeds_are_independent_of_level_and_stable():
    assert trial_seeds(0, 3) == trial_seeds(0, 3)
    assert len({trial_seeds(0, k) for k in range(50)}) == 50
    a, b = trial_seeds(1, 0)
    assert a != b
    assert json.dumps(trial_seeds(0, 0))  # plain ints


# ------------------------------------------------------------------------- the figure of Figs. 13 and 14
def synthetic_summary(dc, efc, kind_columns=True):
    """A summary as robustness.summarize_sweep returns it, for levels 1, 10, 30."""
    from reflexarm.experiments.robustness import summarize_sweep

    rows = []
    for cond, values in (("DC", dc), ("DC+EFC", efc)):
        for level, v in zip((1.0, 10.0, 30.0), values, strict=True):
            for trial, f in enumerate((0.9, 1.1)):
                rows.append(
                    {
                        "kind": "noise",
                        "level": level,
                        "condition": cond,
                        "trial": trial,
                        "msie": v * f,
                        "status": "ok",
                        "g_error_median": 0.001 * level,
                        "M_error_median": 0.0012 * level,
                        "residual1_load_std_Nm": 0.35 * level,
                        "residual1_noise_pred_Nm": 0.34 * level,
                        "compensated1_load_Nm": 13.0 - 0.1 * level,
                        "tau_ext1_load_Nm": 13.0,
                    }
                )
    return summarize_sweep(pd.DataFrame(rows))


def test_sweep_figure_draws_both_controllers_in_one_log_panel_and_marks_a_crossover():
    from reflexarm.experiments.plots import crossover_levels, sweep_figure

    summary = synthetic_summary(dc=[1e-3, 1e-3, 5e-4], efc=[1e-5, 1e-4, 8e-4])  # DC below EFC at 30
    assert crossover_levels(summary) == [30.0]
    fig = sweep_figure(summary, "noise", residual_limit=30.0)
    top = fig.axes[0]
    assert top.get_yscale() == "log"
    labels = [ln.get_label() for ln in top.get_lines()]
    assert labels[:2] == ["DC ($\\kappa_{ext}=0$)", "DC+EFC ($\\kappa_{ext}=1$)"]
    assert labels[2] == "crossover at 30"
    # the mean over the trials, normalised by the largest run of the figure (0.9 and 1.1 x the value)
    peak = 1.1e-3
    np.testing.assert_allclose(top.get_lines()[0].get_ydata(), np.array([1e-3, 1e-3, 5e-4]) / peak)
    np.testing.assert_allclose(top.get_lines()[1].get_ydata(), np.array([1e-5, 1e-4, 8e-4]) / peak)
    assert "DC below DC+EFC from 30" in top.get_title()
    # the mechanism panel: residual noise (measured, predicted), DC's compensated mean and the cut-off line
    low = [ln.get_label() for ln in fig.axes[1].get_lines()]
    assert "predicted std (dq noise)" in low and "mean cut-off res$_1$, DC" in low and "cut-off 30 Nm" in low
    assert fig.axes[-1].get_xlabel() == "noise scale factor [-]"


def test_sweep_figure_of_model_errors_shows_increase_and_achieved_error_without_crossover():
    from reflexarm.experiments.plots import sweep_figure

    summary = synthetic_summary(dc=[1e-3, 1.01e-3, 1.03e-3], efc=[1e-5, 2e-5, 4e-5])
    fig = sweep_figure(summary, "model-error")
    assert len(fig.axes) == 3
    assert "no crossover" in fig.axes[0].get_title()
    assert [ln.get_label() for ln in fig.axes[0].get_lines()][2:] == []  # no crossover line
    inc = {ln.get_label(): ln.get_ydata() for ln in fig.axes[1].get_lines()}
    np.testing.assert_allclose(inc["DC"], [0.0, 1e-5, 3e-5], atol=1e-12)
    np.testing.assert_allclose(inc["DC+EFC"], [0.0, 1e-5, 3e-5], atol=1e-12)
    err = {ln.get_label(): ln.get_ydata() for ln in fig.axes[2].get_lines()}
    np.testing.assert_allclose(err["g(q), median"], [0.1, 1.0, 3.0])  # in percent
    assert fig.axes[2].get_ylabel() == "achieved model error [%]"
