"""Where the detection residual's second stage (K_f, ``Controller(detection_filter_gain=)``) travels with the levels
tuned on it: tune-thresholds writes it, detect and the collision commands read it back (the command line wins), a
detection study records it per arm and the reaction study's tuned pairs use it, the ROS node's parameter; the
refusals. The stage's arithmetic is tested in ``test_detection_filter.py``."""

from __future__ import annotations

import argparse
import json

import pytest

from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.errors import ConfigError
from reflexarm.experiments.tuned_detection import load_tuned_detection

PANDA = load_robot("panda")


def _choice(threshold: str, kf: float | None):
    from reflexarm._cli.common import detection_choice

    args = argparse.Namespace(threshold=threshold, observer_gain=5.0, detection_observer_gain=100.0,
                              observer_discretization=None, reaction="brake", detection_friction_band=None,
                              detection_filter_gain=kf)  # fmt: skip
    return detection_choice(args, PANDA)


def test_the_collision_commands_take_the_stage_from_the_command_line_or_the_tuned_file(tmp_path):
    from reflexarm._cli.collision_settings import setting_line, with_detection
    from reflexarm.experiments.collision import LINK_SETTING

    assert _choice("11", None).detection_filter_gain is None
    tuned = tmp_path / "thresholds.json"  # tune-thresholds' layout: levels and the observer settings they are for
    tuned.write_text(json.dumps({"collision_Nm": [9.0] * 7,
                                 "observer": {"detection_observer_gain": 100.0, "detection_filter_gain": 200.0}}))
    choice = _choice(str(tuned), None)
    assert choice.detection_filter_gain == 200.0 and "a second stage of K_f = 200 1/s" in choice.label()
    assert choice.describe()["detection_filter_gain_per_s"] == 200.0
    assert _choice(str(tuned), 300.0).detection_filter_gain == 300.0  # the command line wins
    setting = with_detection(LINK_SETTING, choice)
    assert setting.detection_filter_gain == 200.0 and "K_f = 200 1/s" in setting_line(setting)
    ctrl = setting.controller(PANDA)
    assert ctrl.detection_filter_gain is not None and set(ctrl.detection_filter_gain) == {200.0}
    for bad in (-1.0, 0.0, float("nan")):
        with pytest.raises(ConfigError, match="--detection-filter-gain must be a positive gain"):
            _choice("11", bad)
    for key, bad in (("detection_filter_gain", "fast"), ("detection_filter_gain", -200.0),
                     ("detection_friction_band", True)):  # fmt: skip
        broken = tmp_path / f"broken_{key}.json"  # a setting the levels were tuned with, unreadable: refused
        broken.write_text(json.dumps({"collision_Nm": [9.0] * 7, "observer": {"detection_observer_gain": 100.0,
                                                                                key: bad}}))  # fmt: skip
        with pytest.raises(ConfigError, match=f"its observer setting {key} must be a positive number or null"):
            _choice(str(broken), None)


def test_a_detection_study_s_stage_reaches_the_tuned_pair_and_a_bad_one_is_refused(tmp_path):
    from test_detection_friction import study_file

    def study(kf: object) -> str:
        return study_file(tmp_path, detection_filter_gain=kf)

    joints = {"panda": PANDA.joint_names}
    tuned = load_tuned_detection(study(200.0), ["panda"], joints)["panda"]
    assert tuned.filter_gain == 200.0 and tuned.as_dict()["detection_filter_gain_per_s"] == 200.0
    assert load_tuned_detection(study(None), ["panda"], joints)["panda"].filter_gain is None
    from reflexarm.experiments.reaction_study import _setting

    ctrl = _setting("link", "brake", tuned).controller(PANDA)
    assert ctrl.detection_filter_gain is not None and set(ctrl.detection_filter_gain) == {200.0}
    for bad in (-1.0, 0.0, "fast", True):
        with pytest.raises(ConfigError, match="detection_filter_gain must be a positive gain"):
            load_tuned_detection(study(bad), ["panda"], joints)


def test_the_ros_node_s_controller_takes_the_stage_from_its_parameter_or_the_tuned_file(tmp_path):
    from reflexarm.ros.config import MonitorConfig
    from reflexarm.ros.controller_setup import build_controller

    def built(**values: object) -> Controller:
        return build_controller(MonitorConfig.from_values("monitor", {"robot": "panda", **values}), PANDA)

    assert built(detection_observer_gain=100.0).detection_filter_gain is None
    assert set(built(detection_observer_gain=100.0, detection_filter_gain=150.0).detection_filter_gain) == {150.0}
    tuned = tmp_path / "thresholds.json"
    tuned.write_text(json.dumps({"collision_Nm": [9.0] * 7,
                                 "observer": {"detection_observer_gain": 100.0, "detection_filter_gain": 250.0}}))
    ctrl = built(detection_observer_gain=100.0, threshold=str(tuned))
    assert set(ctrl.detection_filter_gain) == {250.0}
    for bad in (-1.0, float("nan")):
        with pytest.raises(ConfigError, match="detection_filter_gain and rearm_after must be >= 0"):
            built(detection_observer_gain=100.0, detection_filter_gain=bad)


def test_tune_thresholds_writes_the_stage_and_detect_replays_with_it(tmp_path, capsys):
    """tune-thresholds with --detection-filter-gain records K_f with the levels (and the pairs of
    --detection-gains); detect replays with the file's stage (printed), unless the command line gives another; the
    stage's levels are lower than the first order's on the same log (its noise is filtered); a bad K_f is refused."""
    from impact_logs import impact_log
    from reflexarm.cli import main
    from reflexarm.logs import save_log

    iiwa = load_robot("iiwa14")
    # 2 min: the stage's declustering gap, 5 (1/k_o + 1/K_f) = 75 ms, leaves too few excursions in 1 min for a tail
    free = save_log(impact_log(iiwa, rate_hz=1000.0, duration_s=120, seed=11).log, tmp_path / "free.parquet")
    base = (f"tune-thresholds {free} --robot iiwa14 --detection-observer-gain 100 --rate 10 --contact-rate 600 "
            "--allow-extrapolation --no-figure")  # fmt: skip
    assert main([*base.split(), "--out", str(tmp_path / "first")]) == 0
    assert main([*base.split(), "--detection-filter-gain", "200", "--detection-gains", "100,200",
                 "--out", str(tmp_path / "thr")]) == 0  # fmt: skip
    capsys.readouterr()
    first = json.loads((tmp_path / "first" / "thresholds.json").read_text())
    doc = json.loads((tmp_path / "thr" / "thresholds.json").read_text())
    assert doc["observer"]["detection_filter_gain"] == 200.0 and first["observer"]["detection_filter_gain"] is None
    assert all(p["detection_filter_gain"] == 200.0 for p in doc["detection_pairs"]["pairs"])
    assert all(a < b for a, b in zip(doc["collision_Nm"], first["collision_Nm"], strict=True))
    thr = tmp_path / "thr" / "thresholds.json"
    common = ["detect", str(free), "--robot", "iiwa14", "--threshold", str(thr), "--no-figure"]
    assert main([*common, "--out", str(tmp_path / "d1")]) == 0
    assert "its residual through a second stage of K_f = 200 1/s" in capsys.readouterr().out
    assert main([*common, "--detection-filter-gain", "400", "--out", str(tmp_path / "d2")]) == 0
    assert "K_f = 400 1/s" in capsys.readouterr().out
    assert main([*common, "--detection-filter-gain", "-1", "--out", str(tmp_path / "d3")]) != 0
    assert "--detection-filter-gain must be a positive gain" in capsys.readouterr().err
    assert main([*base.split(), "--detection-filter-gain", "0", "--out", str(tmp_path / "bad")]) != 0
    assert "--detection-filter-gain must be a positive gain" in capsys.readouterr().err


def test_detection_study_refuses_a_bad_stage_before_its_runs():
    from reflexarm.experiments.detection_study import study_arm_detection
    from reflexarm.experiments.reaction_study import study_arm

    with pytest.raises(ConfigError, match="detection_filter_gain"):
        study_arm_detection(study_arm("panda"), [100.0], detection_filter_gain=-5.0)
