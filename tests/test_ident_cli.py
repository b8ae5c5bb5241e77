"""The command line: excite, identify friction / dynamics, validate; errors name the file and column."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, plan_friction_experiment, save_log
from reflexarm.ident.excitation.design import FourierTrajectory


def _exact_log(robot, trajectory, duration):
    t = np.arange(0.0, duration, 1e-3)
    q, dq, ddq = trajectory.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return RobotLog(t, q, dq, tau, source="exact")


def test_excite_writes_the_trajectory_and_reports_condition_numbers(tmp_path, capsys):
    out = tmp_path / "exc"
    code = main(["excite", "--robot", "panda", "--harmonics", "3", "--maxiter", "3", "--out", str(out), "--quiet"])
    assert code == 0
    text = capsys.readouterr().out
    assert "base parameters: 43 of 70" in text and "condition number of the base regressor:" in text
    doc = json.loads((out / "excitation.json").read_text())
    assert doc["condition_optimized"] <= doc["condition_initial"]
    assert (out / "excitation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # content: test_ident_plots.py
    FourierTrajectory.from_dict(doc["trajectory"])


def test_identify_friction_from_user_logs(tmp_path, capsys, atlas):
    plan = plan_friction_experiment(atlas, 0, speeds=(0.2, 0.5, 1.0))
    log = _exact_log(atlas, plan, plan.duration)
    p = save_log(log, tmp_path / "runs_j1.parquet")
    code = main(["identify", "friction", "--run", f"1={p}", "--out", str(tmp_path / "fr"), "--quiet"])
    assert code == 0
    doc = json.loads((tmp_path / "fr" / "friction.json").read_text())
    # exact data, segments found from the data itself (the plan is not given)
    assert doc["coulomb"][0] == pytest.approx(2.0, rel=0.01) and doc["viscous"][0] == pytest.approx(1.3, rel=0.01)
    # joints 2-7 had no run: not identified (null), never a friction of 0 (tests/test_friction_file.py)
    assert doc["identified_joints"] == [1] and doc["coulomb"][1:] == [None] * 6 and doc["viscous"][1:] == [None] * 6
    assert (tmp_path / "fr" / "fig4_friction.png").exists()
    assert "mu_C [Nm]" in capsys.readouterr().out


@pytest.mark.slow  # ~45 s: a simulated log, identification and validation
def test_identify_dynamics_and_validate_from_a_log(tmp_path, capsys, atlas):
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), atlas.home)
    log = _exact_log(atlas, tr.with_periods(2), 20.0)
    p = save_log(log, tmp_path / "exc.csv")
    fr = tmp_path / "friction.json"
    fr.write_text(json.dumps(FrictionParameters.from_model(atlas.friction).to_dict()))
    out = tmp_path / "dyn"
    args = ["identify", "dynamics", "--log", str(p), "--split", "0.6", "--friction", str(fr), "--out", str(out)]
    assert main([*args, "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "43 base parameters of 70" in text and "pooled validation RMSE (sequential)" in text
    for name in ("model_sequential.json", "model_combined.json", "validation.csv", "fig6_torques.png"):
        assert (out / name).exists(), name
    code = main(["validate", "--model", str(out / "model_sequential.json"), "--log", str(p), "--out",
                 str(tmp_path / "val"), "--quiet"])  # fmt: skip
    assert code == 0
    assert "pooled RMSE:" in capsys.readouterr().out


def test_malformed_log_fails_with_file_and_column(tmp_path, capsys, atlas):
    p = tmp_path / "bad.csv"
    p.write_text("t,q_1,dq_1,tau_1\n0,0,0,0\n0.001,0,0,0\n")
    code = main(["identify", "dynamics", "--log", str(p), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 2
    err = capsys.readouterr().err
    assert "reflexarm identify: error: bad.csv: the log has 1 joints (q_1..q_1); the robot has 7" in err
    p.write_text("t,q_1,dq_1\n0,0,0\n")
    code = main(["identify", "dynamics", "--log", str(p), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 2
    assert "bad.csv: column 'tau_1' missing; found: t, q_1, dq_1" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_dynamics_saves_the_models_whose_table_it_prints(tmp_path, capsys):
    """Table I end to end: the simulated study prints the validation MSE of two models, and 'validate'
    on the log it wrote gives the same per-joint MSE for the saved model files (the same models, the
    same rows of the same log: equal to round-off)."""
    from excitation_data import DATA

    out = tmp_path / "study"
    assert main(["identify", "dynamics", "--excitation", str(DATA), "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "Both methods identified from the same rows" in text and "sequential against combined:" in text
    table = json.loads((out / "study.json").read_text())["table"]
    for method in ("combined", "sequential"):
        code = main(["validate", "--model", str(out / f"model_{method}.json"), "--log", str(out / "validation_log.npz"),
                     "--friction-model", "identified", "--out", str(tmp_path / method), "--quiet"])  # fmt: skip
        assert code == 0
        rows = json.loads((tmp_path / method / "validate.json").read_text())["validation"]["rows"]
        np.testing.assert_allclose(
            [r["mse"] for r in rows], [r[f"mse_{method}"] for r in table], rtol=1e-9, err_msg=method
        )
