"""The paper's robustness sweeps (Figs. 13, 14) at reduced size, on real closed-loop runs.

Levels and trials are reduced (the default sweeps are 30 levels x 10 trials x 2 settings); the claims
are checked at the levels run. Seeds fixed, so every number here is reproducible.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from reflexarm.cli import main as cli_main
from reflexarm.experiments.compensation import CompensationSetup
from reflexarm.experiments.robustness import paper_sweep, paper_sweep_tasks

pytestmark = pytest.mark.slow

LEVELS = "1,30"  # the ends of Fig. 13's range
TRIALS = 2


@pytest.fixture(scope="module")
def model_error_dry(tmp_path_factory):
    out = tmp_path_factory.mktemp("me_dry")
    setup = CompensationSetup(plant_friction="dry")
    return out, paper_sweep(
        "model-error", out, levels=LEVELS, trials=TRIALS, seed=0, setup=setup, workers=2, progress=False
    )


def wide(summary, column="norm_mean"):
    return summary.pivot(index="level", columns="condition", values=column)


def test_model_error_sweep_outputs(model_error_dry):
    out, res = model_error_dry
    assert len(res.sweep.table) == 2 * 2 * TRIALS and set(res.sweep.table["status"]) == {"ok"}
    for f in res.files.values():
        assert Path(f).exists()
    assert (out / "reference.npz").exists()
    pd.testing.assert_frame_equal(pd.read_parquet(res.files["results_parquet"]), res.sweep.table)
    assert res.summary["norm_max"].max() == pytest.approx(1.0)  # normalised by the figure's maximum


def test_model_error_sweep_efc_below_dc_at_every_level(model_error_dry):
    # Fig. 13: with EFC the deviation from the compliant reference is far below DC without EFC at every
    # level. Default plant (dry friction): measured ratio ~5.3 at every level, not the 10x of the issue;
    # the next test shows where the EFC's remaining MSIE comes from, the one after shows 10x without
    # stiction. Asserted here with margin: at least 4x.
    _, res = model_error_dry
    w = wide(res.summary)
    assert (w["DC"] / w["DC+EFC"]).min() > 4.0
    # the model errors themselves are compensated: from 1 % to 30 % the curves stay flat (within 10 %)
    for cond in ("DC", "DC+EFC"):
        assert w[cond].max() / w[cond].min() < 1.1


def test_model_error_sweep_efc_remainder_is_stiction_of_joints_2_to_4(model_error_dry):
    # the reference run (no DC) keeps shx, ely, elx stuck by dry friction; the DC+EFC run compensates
    # their friction and they yield: >= 80 % of the EFC's MSIE comes from these three joints
    _, res = model_error_dry
    t = res.sweep.table
    efc = t[t["condition"] == "DC+EFC"]
    share = efc[["msie_j2", "msie_j3", "msie_j4"]].sum(axis=1) / efc[[f"msie_j{i}" for i in range(1, 8)]].sum(axis=1)
    assert share.min() > 0.8


def test_model_error_sweep_ten_times_below_on_the_papers_plant(tmp_path):
    # the default setup is the paper's simulated arm, continuous-time Coulomb + viscous friction (no
    # stiction): the EFC curve is >= 10x below the DC curve at the levels run (measured ~11x)
    res = paper_sweep("model-error", tmp_path, levels=LEVELS, trials=1, seed=0, workers=2, progress=False)
    w = wide(res.summary)
    assert (w["DC"] / w["DC+EFC"]).min() >= 10.0


def test_noise_sweep_scale_10_within_factor_2_of_scale_1(tmp_path):
    # Fig. 14: noise up to 10x the paper's levels does not change the deviation noticeably
    res = paper_sweep("noise", tmp_path, levels="1,10", trials=TRIALS, seed=0, workers=2, progress=False)
    w = wide(res.summary)
    for cond in ("DC", "DC+EFC"):
        ratio = w.loc[10.0, cond] / w.loc[1.0, cond]
        assert 0.5 <= ratio <= 2.0, (cond, ratio)


KILL_ARGS = ["sweep", "model-error", "--levels", LEVELS, "--trials", str(TRIALS), "--workers", "1", "--quiet",
             "--plant-friction", "dry"]  # fmt: skip
DRY = CompensationSetup(plant_friction="dry")


def test_killed_cli_sweep_resumes_to_the_same_table(model_error_dry, tmp_path):
    # `reflexarm sweep model-error` killed (SIGKILL) after 3 stored runs, then restarted: exactly the
    # missing runs run, the reference is not recomputed, the table equals the uninterrupted sweep's
    _, full = model_error_dry
    out = tmp_path / "killed"
    script = "import sys; from reflexarm.cli import main; sys.exit(main(sys.argv[1:]))"
    proc = subprocess.Popen(
        [sys.executable, "-c", script, *KILL_ARGS, "--out", str(out)],
        env={**os.environ, "MPLBACKEND": "Agg"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 180
        while time.time() < deadline and len(list(out.glob("runs/*.json"))) < 3 and proc.poll() is None:
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    stored = {p.stem for p in out.glob("runs/*.json")}
    all_keys = {t.key for t in paper_sweep_tasks("model-error", LEVELS, TRIALS, 0)}
    assert 3 <= len(stored) < len(all_keys)
    ref_mtime = (out / "reference.npz").stat().st_mtime_ns
    res = paper_sweep("model-error", out, levels=LEVELS, trials=TRIALS, seed=0, setup=DRY, workers=2, progress=False)
    assert sorted(res.sweep.ran) == sorted(all_keys - stored)
    assert sorted(res.sweep.skipped) == sorted(stored)
    assert (out / "reference.npz").stat().st_mtime_ns == ref_mtime
    pd.testing.assert_frame_equal(res.sweep.table, full.sweep.table)


def test_real_runs_on_a_dask_local_cluster(model_error_dry, tmp_path):
    from distributed import LocalCluster

    _, full = model_error_dry
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        res = paper_sweep(
            "model-error",
            tmp_path,
            levels="1",
            trials=1,
            seed=0,
            setup=DRY,
            scheduler=cluster.scheduler_address,
            progress=False,
        )
    got = res.sweep.table.set_index(["level", "condition", "trial"])["msie"]
    want = full.sweep.table.set_index(["level", "condition", "trial"])["msie"].loc[got.index]
    np.testing.assert_array_equal(got.to_numpy(), want.to_numpy())  # bit-identical, wherever it ran


@pytest.mark.parametrize(
    "argv, message",
    [
        (["sweep", "noise", "--levels=-5,1"], "levels must be non-negative; got -5"),
        (["sweep", "model-error", "--levels", "150"], "model-error levels are percentages below 100; got 150"),
        (["sweep", "noise", "--levels", "1", "--trials", "0"], "trials must be a positive integer; got 0"),
        (["sweep", "noise", "--levels", "1", "--workers", "0"], "workers must be a positive integer; got 0"),
        (["efc-step", "--model-error=-3"], "--model-error must be non-negative [%]; got -3"),
    ],
)
def test_cli_bad_input_is_a_clear_error(argv, message, tmp_path, capsys):
    assert cli_main([*argv, "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and "error:" in err


def test_unreachable_scheduler_fails_before_any_run(tmp_path):
    from reflexarm.errors import ConfigError

    with pytest.raises(ConfigError, match="cannot reach the Dask scheduler at 'tcp://127.0.0.1:9' within 1 s"):
        paper_sweep(
            "noise",
            tmp_path,
            levels="1",
            trials=1,
            scheduler="tcp://127.0.0.1:9",
            scheduler_timeout=1.0,
            progress=False,
        )
    assert not (tmp_path / "reference.npz").exists()  # refused before spending a run on the reference
