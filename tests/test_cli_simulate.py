"""The collision and velocity-tracking commands: the controller's model options, what they print and write."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm._cli.common import (
    DEFAULT_MODEL_ERROR_PERCENT,
    ModelChoice,
    detection_choice,
    model_choice,
    read_threshold,
    tuned_gain_note,
)
from reflexarm.cli import build_parser, main
from reflexarm.errors import ConfigError
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, identify_dynamics, save_identified_model
from reflexarm.ident.excitation.design import FourierTrajectory
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


# ------------------------------------------------------------------------------ detection settings on the CLI
DETECTING = (["demo"], ["simulate", "ee-collision"], ["simulate", "link-collision"])


@pytest.mark.parametrize("command", [*DETECTING, ["mode-table"]], ids=lambda c: " ".join(c))
def test_detection_defaults_are_the_papers(command, atlas):
    choice = detection_choice(build_parser().parse_args(command), atlas)
    assert choice.threshold == 11.0 and choice.detection_observer_gain is None
    if command == ["mode-table"]:  # the supervised push of Fig. 3: the setup's k_o, the compliant switch
        assert (choice.observer_gain, choice.reaction) == (None, "compliant")
    else:
        assert (choice.observer_gain, choice.reaction) == (5.0, "gravity")


def test_threshold_is_a_level_a_list_or_a_tuned_file(tmp_path, atlas):
    assert read_threshold("8.5", atlas) == (8.5, "command line", None)
    assert read_threshold("1,2,3,4,5,6,7", atlas) == ((1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0), "command line", None)
    # what 'reflexarm tune-thresholds' writes: collision_Nm per joint, the joints' names, the observer
    doc = {
        "collision_Nm": [12.5, 13, 14, 15, 1.5, 1.25, 1.0],
        "joints": [{"joint": j + 1, "name": name} for j, name in enumerate(atlas.joint_names)],
        "observer": {"observer_gain": 5.0, "detection_observer_gain": 50.0},
    }
    path = tmp_path / "thresholds.json"
    path.write_text(json.dumps(doc))
    assert read_threshold(str(path), atlas) == ((12.5, 13.0, 14.0, 15.0, 1.5, 1.25, 1.0), str(path), 50.0)
    args = build_parser().parse_args(["demo", "--threshold", str(path)])
    note = tuned_gain_note(detection_choice(args, atlas), 5.0)
    assert note is not None and "tuned for a detecting k_o = 50 1/s; this run detects with k_o = 5 1/s" in note


def test_bad_thresholds_and_gains_name_the_value(tmp_path, atlas):
    with pytest.raises(ConfigError, match=r"--threshold has 3 levels; robot 'atlas_v5_left_arm' has 7 joints \(l_arm"):
        read_threshold("1,2,3", atlas)
    with pytest.raises(ConfigError, match=r"--threshold levels must be positive torques \[Nm\]; got '-3'"):
        read_threshold("-3", atlas)
    with pytest.raises(ConfigError, match=r"--threshold expects a level \[Nm\], a comma list of 7 levels or a "):
        read_threshold("eleven", atlas)
    with pytest.raises(ConfigError, match=r"--threshold '.*nope\.json': no such file"):
        read_threshold(str(tmp_path / "nope.json"), atlas)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"--threshold '.*bad\.json' is not a JSON file"):
        read_threshold(str(bad), atlas)
    bad.write_text(json.dumps({"contact_Nm": [1] * 7}))
    with pytest.raises(ConfigError, match=r"has no 'collision_Nm' list of numbers \(write it with 'reflexarm tune"):
        read_threshold(str(bad), atlas)
    bad.write_text(json.dumps({"collision_Nm": [1] * 6}))
    with pytest.raises(ConfigError, match=r"has 6 levels; robot 'atlas_v5_left_arm' has 7 joints"):
        read_threshold(str(bad), atlas)
    bad.write_text(json.dumps({"collision_Nm": [1] * 7, "joints": [{"name": f"j{k}"} for k in range(7)]}))
    with pytest.raises(ConfigError, match=r"is for joints \['j0', .*\]; robot 'atlas_v5_left_arm' has \['l_arm_shz'"):
        read_threshold(str(bad), atlas)
    parser = build_parser()
    with pytest.raises(ConfigError, match=r"--observer-gain must be a positive gain \[1/s\]; got -5"):
        detection_choice(parser.parse_args(["demo", "--observer-gain", "-5"]), atlas)
    with pytest.raises(ConfigError, match=r"--detection-observer-gain must be a positive gain \[1/s\]; got 0"):
        detection_choice(parser.parse_args(["demo", "--detection-observer-gain", "0"]), atlas)
    with pytest.raises(SystemExit):  # argparse names the choices
        parser.parse_args(["demo", "--reaction", "stop"])


def test_link_collision_runs_with_the_given_detection_and_reports_the_event(tmp_path, capsys):
    out = tmp_path / "link"
    argv = ["simulate", "link-collision", "--out", str(out), "--quiet", "--model-error", "0"]
    argv += ["--threshold", "9", "--observer-gain", "10", "--detection-observer-gain", "40", "--reaction", "compliant"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "detection zeta = 9 Nm, k_o = 10 1/s, detection k_o = 40 1/s, reaction compliant" in captured.err
    assert "KE +0.5 s / det" in captured.out and "re-contact" in captured.out
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["detection"] == {
        "threshold_Nm": 9.0,
        "threshold_source": "command line",
        "observer_gain_per_s": 10.0,
        "detection_observer_gain_per_s": 40.0,
        "observer_discretization": "exact",  # the default with a detection observer
        "detection_friction_band_rad_s": None,
        "detection_filter_gain_per_s": None,  # no second stage
        "reaction": "compliant",
        "reaction_settings": None,  # the defaults
    }
    tr = Trace.load(next(out.glob("link_collision_*.npz")))
    setting = tr.meta["setting"]
    assert (setting["threshold"], setting["observer_gain"], setting["detection_observer_gain"]) == (9.0, 10.0, 40.0)
    assert setting["reaction"] == "compliant" and setting["observer_discretization"] == "exact"
    assert set(tr.mode) >= {"compliant"} and "gravity_compensation" not in set(tr.mode)
    event = row["event"]
    assert event["contact_class"] == "link" and event["detected_s"] == row["detection_s"]
    assert event["contact_point_source"] == "elbow_stick_tip"


def test_a_tuned_file_of_high_levels_reaches_the_controller(tmp_path, atlas):
    """Levels far above any contact torque of the push: no detection (the default 11 Nm detects it)."""
    path = tmp_path / "thresholds.json"
    path.write_text(json.dumps({"collision_Nm": [1000.0] * 7}))
    out = tmp_path / "link"
    assert main(["simulate", "link-collision", "--out", str(out), "--quiet", "--threshold", str(path)]) == 0
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["detection_s"] is None and row["contact_start_s"] is not None
    assert row["detection"]["threshold_Nm"] == [1000.0] * 7 and row["detection"]["threshold_source"] == str(path)
    assert row["event"]["kinetic_energy_at_detection_J"] is None


def test_plant_friction_none_zeroes_the_true_friction_and_damping():
    from reflexarm.experiments.collision import _true_friction
    from reflexarm.robots import load_robot
    from reflexarm.sim import Plant

    iiwa = load_robot("iiwa14")
    with_file = Plant(iiwa, true_friction=_true_friction(iiwa, "file"))
    assert with_file.model.dof_frictionloss.max() > 0 and with_file.model.dof_damping.max() > 0
    bare = Plant(iiwa, true_friction=_true_friction(iiwa, "none"))
    np.testing.assert_array_equal(bare.model.dof_frictionloss, 0.0)
    np.testing.assert_array_equal(bare.model.dof_damping, 0.0)
    with pytest.raises(ConfigError, match="unknown plant_friction 'dry'; choose one of: file, none"):
        _true_friction(iiwa, "dry")
