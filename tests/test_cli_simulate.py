"""The collision and velocity-tracking commands: the controller's model options, what they print and write."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm._cli.common import DEFAULT_MODEL_ERROR_PERCENT, ModelChoice, model_choice
from reflexarm.cli import build_parser, main
from reflexarm.errors import ConfigError
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, identify_dynamics, save_identified_model
from reflexarm.ident.excitation import FourierTrajectory
from reflexarm.sim import Trace

COMMANDS = (
    ["demo"],
    ["simulate", "ee-collision"],
    ["simulate", "link-collision"],
    ["simulate", "free-motion"],
    ["simulate", "velocity-tracking"],
)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c))
def test_every_closed_loop_command_defaults_to_ten_percent_model_error(command):
    args = build_parser().parse_args(command)
    assert model_choice(args) == ModelChoice(DEFAULT_MODEL_ERROR_PERCENT / 100.0, 0, None)
    assert DEFAULT_MODEL_ERROR_PERCENT == 10.0


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c))
def test_model_error_is_a_percentage_with_a_seed(command):
    args = build_parser().parse_args([*command, "--model-error", "5", "--model-seed", "3"])
    choice = model_choice(args)
    assert choice == ModelChoice(0.05, 3, None)
    assert choice.describe() == {"source": "perturbed", "level": 0.05, "seed": 3}
    exact = model_choice(build_parser().parse_args([*command, "--model-error", "0"]))
    assert exact.describe() == {"source": "exact"}


def test_model_options_are_checked(tmp_path):
    parser = build_parser()
    with pytest.raises(ConfigError, match=r"--model-error must be a percentage in \[0, 100\); got 120"):
        model_choice(parser.parse_args(["demo", "--model-error", "120"]))
    with pytest.raises(ConfigError, match=r"--model-error must be a percentage in \[0, 100\); got -1"):
        model_choice(parser.parse_args(["demo", "--model-error", "-1"]))
    missing = tmp_path / "nope.json"
    with pytest.raises(ConfigError, match=r"--model: no such file '.*nope\.json'"):
        model_choice(parser.parse_args(["demo", "--model", str(missing)]))
    missing.write_text("{}")
    with pytest.raises(ConfigError, match=r"is used as identified; got --model-error 5 as well"):
        model_choice(parser.parse_args(["demo", "--model", str(missing), "--model-error", "5"]))
    assert model_choice(parser.parse_args(["demo", "--model", str(missing)])).file == missing


def test_bad_model_file_is_a_clean_error(tmp_path, capsys):
    bad = tmp_path / "model.json"
    bad.write_text("{}")
    code = main(["simulate", "link-collision", "--model", str(bad), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 2
    assert "reflexarm simulate: error:" in capsys.readouterr().err


@pytest.mark.slow
def test_link_collision_prints_the_paper_beside_ours(tmp_path, capsys):
    out = tmp_path / "link"
    assert main(["simulate", "link-collision", "--out", str(out), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "controller model: +-10 % model errors (seed 0)" in captured.err
    row = json.loads((out / "link_collision_summary.json").read_text())[0]
    line = next(ln for ln in captured.out.splitlines() if "link collision: detection delay [s]" in ln)
    assert "~0.1 (5.5 -> 5.6 s)" in line and f"{row['detection_delay_s']:.3f}" in line
    assert (out / "fig10_link_collision.png").is_file()


@pytest.mark.slow
def test_velocity_tracking_command_prints_both_controllers(tmp_path, capsys):
    out = tmp_path / "vt"
    code = main(["simulate", "velocity-tracking", "--travel", "0.4", "--speed", "0.4", "--out", str(out), "--quiet"])
    assert code == 0
    text = capsys.readouterr()
    assert "PD: K_p = 1000 Nm/rad, K_d = 30 Nms/rad" in text.err
    doc = json.loads((out / "velocity_tracking_summary.json").read_text())
    assert [r["controller"] for r in doc["rows"]] == ["PD", "impedance"]
    for r in doc["rows"]:
        line = next(ln for ln in text.out.splitlines() if ln.strip().startswith(r["controller"]))
        assert f"{r['rms_dq_error']:.4f}" in line
    assert doc["controller_model"] == {"source": "perturbed", "level": 0.1, "seed": 0}
    assert (doc["setup"]["joint"], doc["setup"]["joint_name"]) == (4, "l_arm_elx")  # 1-based, as --joint
    assert (out / "fig5_velocity_tracking.png").is_file()


def test_velocity_tracking_rejects_a_joint_out_of_range(tmp_path, capsys):
    assert main(["simulate", "velocity-tracking", "--joint", "9", "--out", str(tmp_path), "--quiet"]) == 2
    assert "--joint must be in 1..7; got 9" in capsys.readouterr().err


@pytest.mark.slow
def test_an_identified_model_file_drives_the_link_collision(tmp_path, capsys, atlas):
    """``--model FILE``: the model identified from an exact log (so: close to the plant's) is the one the
    controller runs on, and the push is detected with it."""
    rng = np.random.default_rng(0)
    coef = 0.15 * rng.normal(size=(2, 7, 5))
    traj = FourierTrajectory(2 * np.pi * 0.1, coef[0], coef[1], atlas.home)
    t = np.arange(0.0, 10.0, 1e-3)  # one period of the 0.1 Hz excitation
    q, dq, ddq = traj.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    result = identify_dynamics(atlas, RobotLog(t, q, dq, tau, ddq=ddq, source="exact"), friction=fr)
    model_file = tmp_path / "model.json"
    save_identified_model(result, atlas, model_file)
    capsys.readouterr()
    out = tmp_path / "link"
    assert main(["simulate", "link-collision", "--model", str(model_file), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"controller model: identified model {model_file}" in err
    row = json.loads((out / "link_collision_summary.json").read_text())[0]
    # command-line summaries number joints from 1, with the names beside them (the Python summary: 0-based)
    assert row["detection_s"] is not None and row["detected_joints"] == [1]
    assert row["detected_joint_names"] == ["l_arm_shz"]
    tr = Trace.load(next(out.glob("*.npz")))
    assert tr.meta["controller_model"] == {"source": "identified", "file": str(model_file)}
