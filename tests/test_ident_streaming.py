"""Identification from table logs read in blocks (reflexarm.logs.blocks, reflexarm.ident.estimation.streaming)
against the same log read whole (load_log, preprocess_log, identify_dynamics): a short generated log, blocks far
smaller than it (and than the filter's overlap), so that block edges, windows that span several blocks and
segment edges at a long gap are all exercised."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.errors import DataError, ImplausibleDataError
from reflexarm.ident import (
    BatchRegressor,
    FrictionParameters,
    RobotLog,
    identify_dynamics,
    load_log,
    preprocess_log,
    save_log,
)
from reflexarm.ident.estimation.streaming import identify_dynamics_streamed
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.logs.block_scan import scan_table
from reflexarm.logs.blocks import preprocessed_blocks, window_overlap
from reflexarm.logs.plausibility import check_log_against_robot
from reflexarm.logs.preprocessing import plan_preprocessing

N_ROWS = 20_000
#: Blocks of 2,500 rows: 8 blocks, each smaller than the filter's overlap (1,917 samples on each side at
#: 10 Hz / 1 kHz), so every window spans two to three blocks.
BLOCK_ROWS = 2_500
#: Preprocessed signals, relative to each column's largest magnitude. The zero-phase Butterworth filter in
#: transfer-function form (scipy's filtfilt with b, a, as preprocess_log runs it) carries a rounding noise of
#: ~1e-10 relative at fc / fs = 0.02 (measured against sosfiltfilt: 9.6e-11); a window started elsewhere
#: reproduces the whole log's rounding only to that level (measured: 3e-11 on q, 2.4e-10 on ddq, which is dq
#: differentiated at 1 kHz). The overlap's own truncation, r^1917 = 1e-20, is far below.
SIGNAL_RTOL = 1e-9
#: beta_b, as |delta beta_b| / |beta_b|: the signals' 1e-10 times the condition number (~40 here) bounds it
#: by ~4e-9 in the worst direction; measured 3e-11 (combined) and 7e-11 (sequential).
BETA_RTOL = 1e-9
#: Validation MSE per joint: the predictions carry the states' 1e-10 of the torque (~50 Nm), the errors are the
#: torque noise (0.05 Nm): d(MSE) / MSE ~ 2 x 1e-10 x 50 / 0.05 = 2e-7.
VALIDATION_RTOL = 1e-6


def _write_log(robot, path, *, gap=False, rows=N_ROWS, seed=0, noise=1.0):
    rng = np.random.default_rng(seed)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), robot.home)
    t = 1e-3 * np.arange(rows)
    if gap:  # 0.5 s: longer than the 25 periods that are filled, so the log is two segments
        t[rows // 2 :] += 0.5
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    tau += noise * 0.05 * rng.normal(size=tau.shape)
    dq = dq + noise * 0.01 * rng.normal(size=dq.shape)
    return save_log(RobotLog(t, q, dq, tau, source="generated"), path)


def _scan(robot, path, **kw):
    return scan_table(path, joint_names=tuple(robot.joint_names), block_rows=BLOCK_ROWS, **kw)


@pytest.mark.parametrize(("suffix", "gap"), [(".csv", False), (".parquet", True)])
def test_preprocessed_blocks_equal_preprocess_log(atlas, tmp_path, suffix, gap):
    path = _write_log(atlas, tmp_path / f"log{suffix}", gap=gap)
    whole = preprocess_log(load_log(path, joint_names=tuple(atlas.joint_names)))
    table = _scan(atlas, path)
    plan = plan_preprocessing(table.t, table.source, has_ddq=table.has_ddq, has_wrench=table.has_wrench)
    assert window_overlap(plan) > BLOCK_ROWS / 2
    blocks = list(preprocessed_blocks(table, plan, BLOCK_ROWS))
    assert len(blocks) >= N_ROWS // BLOCK_ROWS
    assert table.notes + plan.notes == whole.notes
    np.testing.assert_array_equal(np.concatenate([b.t for b in blocks]), whole.t)
    for name in ("q", "dq", "tau", "ddq", "tau_raw"):
        streamed, desired = np.concatenate([getattr(b, name) for b in blocks]), getattr(whole, name)
        np.testing.assert_allclose(
            streamed, desired, rtol=0, atol=SIGNAL_RTOL * np.abs(desired).max(), err_msg=f"{name} ({suffix})"
        )


@pytest.mark.parametrize(("suffix", "gap"), [(".csv", False), (".parquet", True)])
def test_streamed_identification_equals_the_in_memory_one(atlas, tmp_path, suffix, gap):
    path = _write_log(atlas, tmp_path / f"log{suffix}", gap=gap)
    friction = FrictionParameters.from_model(atlas.friction)
    whole = preprocess_log(load_log(path, joint_names=tuple(atlas.joint_names)))
    with pytest.warns(UserWarning):  # the short log determines M(q) poorly; both paths say so
        streamed = identify_dynamics_streamed(
            atlas, [_scan(atlas, path)], ["combined", "sequential"], block_rows=BLOCK_ROWS, friction=friction
        )
    for method, result in streamed.items():
        with pytest.warns(UserWarning):
            desired = identify_dynamics(atlas, whole, method=method, friction=friction)
        scale = np.linalg.norm(desired.beta_b)
        np.testing.assert_allclose(result.beta_b, desired.beta_b, rtol=0, atol=BETA_RTOL * scale, err_msg=method)
        np.testing.assert_allclose(result.noise_variance, desired.noise_variance, rtol=1e-8, err_msg=method)
        np.testing.assert_allclose(result.residual_rms, desired.residual_rms, rtol=1e-8, err_msg=method)
        assert result.n_samples == desired.n_samples == len(whole)
        assert result.notes == desired.notes


def test_cli_reads_in_blocks_with_the_same_models(atlas, tmp_path, capsys):
    path = _write_log(atlas, tmp_path / "log.parquet")
    fr = tmp_path / "friction.json"
    fr.write_text(json.dumps(FrictionParameters.from_model(atlas.friction).to_dict()))
    beta = {}
    for rows in (0, BLOCK_ROWS):
        out = tmp_path / f"out{rows}"
        args = ["identify", "dynamics", "--robot", "atlas_v5_left_arm", "--log", str(path), "--friction", str(fr),
                "--block-rows", str(rows), "--no-projection", "--out", str(out)]  # fmt: skip
        assert main(args) == 0
        text = capsys.readouterr().out
        assert (f"in blocks of {rows:,} rows" in text) == (rows > 0)
        beta[rows] = {
            m: np.array(json.loads((out / f"model_{m}.json").read_text())["identification"]["beta_b"])
            for m in ("combined", "sequential")
        }
    for m, desired in beta[0].items():
        scale = np.linalg.norm(desired)
        np.testing.assert_allclose(beta[BLOCK_ROWS][m], desired, rtol=0, atol=BETA_RTOL * scale, err_msg=m)


@pytest.mark.slow  # ~60 s: the model is projected onto consistent parameters (the controller's model)
def test_cli_validates_in_blocks_with_the_same_numbers(atlas, tmp_path, capsys):
    """validate: per-joint sums over the blocks (the plot decimated) against the log read whole."""
    path = _write_log(atlas, tmp_path / "log.parquet")
    exact = _write_log(atlas, tmp_path / "exact.npz", noise=0.0)
    args = ["identify", "dynamics", "--robot", "atlas_v5_left_arm", "--log", str(exact), "--method", "combined",
            "--out", str(tmp_path / "model"), "--quiet"]  # fmt: skip
    assert main(args) == 0
    model = tmp_path / "model" / "model_combined.json"
    tables = {}
    for rows in (0, BLOCK_ROWS):
        out = tmp_path / f"val{rows}"
        args = ["validate", "--model", str(model), "--robot", "atlas_v5_left_arm",
                "--log", str(path), "--block-rows", str(rows), "--out", str(out), "--quiet"]  # fmt: skip
        assert main(args) == 0
        assert ("in blocks of" in capsys.readouterr().out) == (rows > 0)
        tables[rows] = json.loads((out / "validate.json").read_text())["validation"]
        assert (out / "fig6_torques.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for key in ("mse", "rmse", "nrmse", "torque_std"):
        np.testing.assert_allclose(
            [r[key] for r in tables[BLOCK_ROWS]["rows"]], [r[key] for r in tables[0]["rows"]], rtol=VALIDATION_RTOL,
            err_msg=key,
        )  # fmt: skip
    assert tables[BLOCK_ROWS]["friction_model"] == tables[0]["friction_model"]


def test_bad_value_in_a_late_block_names_the_file_row(atlas, tmp_path):
    path = _write_log(atlas, tmp_path / "log.csv")
    lines = path.read_text().splitlines()
    row = 17_345  # data row (line row + 2 of the file), in the seventh block
    cells = lines[row + 1].split(",")
    cells[8] = "nan"  # dq_1
    lines[row + 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError) as whole:
        load_log(path, joint_names=tuple(atlas.joint_names))
    table = _scan(atlas, path)
    with pytest.raises(DataError) as streamed:
        identify_dynamics_streamed(atlas, [table], ["combined"], block_rows=BLOCK_ROWS)
    assert f"column 'dq_1' row {row} is NaN" in str(whole.value)
    assert str(streamed.value) == str(whole.value)


def test_implausible_torque_in_a_late_block_names_the_file_row(atlas, tmp_path):
    path = _write_log(atlas, tmp_path / "log.parquet")
    log = load_log(path, joint_names=tuple(atlas.joint_names))
    tau = log.tau.copy()
    row = 15_001
    tau[row, 2] = 20 * atlas.effort_limit[2]  # beyond 10 x the effort limit
    save_log(RobotLog(log.t, log.q, log.dq, tau, source="bad"), path)
    bad = load_log(path, joint_names=tuple(atlas.joint_names))
    with pytest.raises(ImplausibleDataError) as whole:
        check_log_against_robot(bad, atlas)
    with pytest.raises(ImplausibleDataError) as streamed:
        identify_dynamics_streamed(atlas, [_scan(atlas, path)], ["combined"], block_rows=BLOCK_ROWS)
    assert [(s.row, s.column) for s in streamed.value.samples] == [(row, "tau_3")]
    assert str(streamed.value) == str(whole.value)


def test_degrees_on_one_joint_are_refused_from_block_statistics(atlas, tmp_path):
    """The unit checks need the whole log (windows of 50 ms over it, 2,000 model samples spread over it): the
    streamed path gathers them over the blocks and refuses the same log with the same message."""
    path = _write_log(atlas, tmp_path / "log.parquet")
    log = load_log(path, joint_names=tuple(atlas.joint_names))
    dq = log.dq.copy()
    dq[:, 5] *= 3.0  # a gear ratio on one velocity column: q changes a third of the integral of dq
    save_log(RobotLog(log.t, log.q, dq, log.tau, source="bad"), path)
    bad = load_log(path, joint_names=tuple(atlas.joint_names))
    with pytest.raises(ImplausibleDataError) as whole:
        check_log_against_robot(bad, atlas)
    with pytest.raises(ImplausibleDataError) as streamed:
        identify_dynamics_streamed(atlas, [_scan(atlas, path)], ["combined"], block_rows=BLOCK_ROWS)
    assert "q_6" in str(whole.value) and "integral" in str(whole.value)
    assert str(streamed.value) == str(whole.value)


def test_jittery_stamps_are_read_whole_with_the_reason(atlas, tmp_path, capsys):
    path = _write_log(atlas, tmp_path / "log.csv", rows=5_000)
    log = load_log(path, joint_names=tuple(atlas.joint_names))
    t = log.t + 2e-4 * np.random.default_rng(1).uniform(-1, 1, size=log.t.size)  # host stamps, +-0.2 ms
    save_log(RobotLog(t, log.q, log.dq, log.tau, source="jitter"), path)
    out = tmp_path / "out"
    args = ["identify", "dynamics", "--robot", "atlas_v5_left_arm", "--log", str(path), "--method", "combined",
            "--block-rows", "1000", "--no-projection", "--out", str(out), "--quiet"]  # fmt: skip
    with pytest.warns(UserWarning):
        assert main(args) == 0
    text = capsys.readouterr().out
    assert "time steps are not whole periods" in text and "all logs are read whole" in text
