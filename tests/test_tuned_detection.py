"""Tuned detection pairs read back from a ``detection_study.json`` (``reflexarm reaction-study --detection-study``):
the pair chosen per arm, the refusals of a bad file, and a reaction-study run that detects with them.

The study files here are written by the tests (the layout of ``DetectionStudy.write``, numbers chosen by hand), so
that no test depends on a tuning run."""

from __future__ import annotations

import json

import pytest

from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.errors import ConfigError
from reflexarm.experiments.reaction_study import run_reaction_study
from reflexarm.experiments.tuned_detection import TunedDetection, choose_pair, load_tuned_detection

PANDA_JOINTS = tuple(load_robot("panda").joint_names)


def _pair(gain: float, level: float, ramp_s: float, alarms: float | None = 0.0, n: int = 7) -> dict:
    held = None if alarms is None else {"alarms": alarms, "alarms_per_hour": alarms, "duration_s": 3600.0}
    return {"detection_observer_gain": gain, "collision_Nm": [level] * n, "ramp_lag_max_s": ramp_s, "heldout": held}


def _study(tmp_path, pairs: list[dict], joints=PANDA_JOINTS, arm: str = "panda", seed: int | None = 7):
    path = tmp_path / "detection_study.json"
    doc = {
        "conditions": {"gains_per_s": [p["detection_observer_gain"] for p in pairs]},
        "arms": {arm: {"joints": list(joints), "pairs": {"pairs": pairs},
                       "model_seeds": {"mode": "same" if seed is not None else "disjoint", "arm_model_seed": seed}}},
    }  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


# the Atlas row of a detection study: ramp lag within 10 ms first at 100 1/s; 200 1/s had a held-out false alarm
ATLAS_LIKE = [
    _pair(5, 11.5, 0.0604),
    _pair(20, 12.3, 0.0274),
    _pair(50, 15.1, 0.0157),
    _pair(100, 23.8, 0.0096),
    _pair(200, 46.0, 0.0050, alarms=1.0),
    _pair(500, 107.0, 0.0020),
]


def test_auto_takes_the_smallest_gain_within_the_lag_target_without_false_alarms():
    assert choose_pair(ATLAS_LIKE, None, "atlas", "f")["detection_observer_gain"] == 100
    # none within 10 ms: the smallest ramp lag among the pairs without false alarms
    slow = [_pair(5, 11.5, 0.06), _pair(20, 12.3, 0.027), _pair(50, 15.0, 0.015, alarms=3.0)]
    assert choose_pair(slow, None, "atlas", "f")["detection_observer_gain"] == 20
    assert choose_pair(ATLAS_LIKE, 200.0, "atlas", "f")["detection_observer_gain"] == 200  # given: taken as is


def test_a_study_file_gives_each_arm_its_pair_and_model(tmp_path):
    path = _study(tmp_path, [_pair(5, 11.0, 0.06), _pair(200, 30.0, 0.005)])
    (tuned,) = load_tuned_detection(path, ["panda"], {"panda": PANDA_JOINTS}).values()
    assert (tuned.arm, tuned.gain, tuned.levels, tuned.model_seed) == ("panda", 200.0, (30.0,) * 7, 7)
    assert tuned.alarms_per_hour == 0.0 and tuned.as_dict()["levels_Nm"] == [30.0] * 7
    at5 = load_tuned_detection(path, ["panda"], {"panda": PANDA_JOINTS}, gain=5.0)["panda"]
    assert (at5.gain, at5.levels[0]) == (5.0, 11.0)
    assert load_tuned_detection(tmp_path, ["panda"], {"panda": PANDA_JOINTS})["panda"].gain == 200.0  # its folder
    across = _study(tmp_path, [_pair(200, 30.0, 0.005)], seed=None)  # tuned across models: any model seed
    assert load_tuned_detection(across, ["panda"], {"panda": PANDA_JOINTS})["panda"].model_seed is None


@pytest.mark.parametrize(
    ("make", "arms", "gain", "message"),
    [
        (lambda d: d / "missing.json", ["panda"], None, "no such file"),
        (lambda d: (d / "x.json").write_text("{not json") and d / "x.json", ["panda"], None, "is not a JSON file"),
        (lambda d: (d / "y.json").write_text("[1, 2]") and d / "y.json", ["panda"], None, "is not a detection study"),
        (lambda d: _study(d, ATLAS_LIKE), ["iiwa14"], None, "has no arm 'iiwa14' (it has: panda)"),
        (lambda d: _study(d, ATLAS_LIKE, joints=("a", "b")), ["panda"], None, "was tuned for joints ['a', 'b']"),
        (lambda d: _study(d, ATLAS_LIKE), ["panda"], 70.0, "no pair tuned at k_o = 70 1/s (gains: 5, 20, 50, 100"),
        (lambda d: _study(d, [_pair(100, 20.0, 0.009, alarms=2.0)]), ["panda"], None, "no pair without held-out"),
        (lambda d: _study(d, [_pair(100, 20.0, 0.009, alarms=None)]), ["panda"], None, "no pair without held-out"),
        (lambda d: _study(d, [_pair(100, 20.0, 0.009, n=6)]), ["panda"], None, "must be 7 positive torques"),
        (lambda d: _study(d, [_pair(100, -1.0, 0.009)]), ["panda"], None, "must be 7 positive torques"),
        (lambda d: _study(d, ATLAS_LIKE), ["panda"], -5.0, "--detection-gain must be a positive gain"),
    ],
)
def test_a_bad_study_file_is_refused_with_a_reason(tmp_path, make, arms, gain, message):
    path = make(tmp_path)
    with pytest.raises(ConfigError, match=None) as err:
        load_tuned_detection(path, arms, {a: PANDA_JOINTS for a in arms}, gain)
    assert message in str(err.value)


def _tuned(levels: float, gain: float = 200.0, model_seed: int | None = None) -> TunedDetection:
    return TunedDetection("panda", gain, (levels,) * 7, model_seed, "test", 0.0, 0.005)


def test_the_study_detects_with_the_tuned_pair_on_its_model():
    kw = {"reactions": ["brake"], "scenarios": ["demo"], "rest_floors": False}
    paper = run_reaction_study(["panda"], **kw).rows[0]
    assert paper["detected_s"] is not None and paper["detection_gain_per_s"] is None
    # levels no contact of the demo reaches: the tuned pair detects, so nothing is detected
    high = run_reaction_study(["panda"], detection={"panda": _tuned(1e4)}, **kw)
    assert high.rows[0]["detected_s"] is None and high.rows[0]["detection_gain_per_s"] == 200.0
    assert high.conditions["detection"]["panda"]["levels_Nm"] == [1e4] * 7
    # the tuned model seed replaces the study's: the same run as the study at that seed with an untied pair
    tied = run_reaction_study(["panda"], model_seed=0, detection={"panda": _tuned(15.0, model_seed=7)}, **kw)
    free = run_reaction_study(["panda"], model_seed=7, detection={"panda": _tuned(15.0)}, **kw)
    other = run_reaction_study(["panda"], model_seed=0, detection={"panda": _tuned(15.0)}, **kw)
    assert tied.rows[0]["detected_s"] is not None
    assert tied.rows[0]["external_torque_at_detection_Nm"] == free.rows[0]["external_torque_at_detection_Nm"]
    assert tied.rows[0]["kinetic_energy_ratio"] == free.rows[0]["kinetic_energy_ratio"]
    assert tied.rows[0]["kinetic_energy_ratio"] != other.rows[0]["kinetic_energy_ratio"]


def test_the_cli_reads_the_study_and_names_a_bad_gain(tmp_path, capsys):
    path = _study(tmp_path, [_pair(5, 11.0, 0.06), _pair(200, 1e4, 0.005)])
    argv = ["reaction-study", "--arms", "panda", "--scenarios", "demo", "--reactions", "brake"]
    assert main([*argv, "--detection-study", str(path), "--out", str(tmp_path / "o")]) == 0
    captured = capsys.readouterr()
    assert "panda: detection k_o = 200 1/s, zeta = (1e+04, 1e+04" in captured.err and "model seed 7" in captured.err
    doc = json.loads((tmp_path / "o" / "reaction_study.json").read_text())
    assert doc["rows"][0]["detected_s"] is None and doc["conditions"]["detection"]["panda"]["model_seed"] == 7
    for extra, message in (
        (["--detection-gain", "50"], "--detection-gain needs --detection-study"),
        (["--detection-study", str(path), "--detection-gain", "fast"], "--detection-gain must be a gain [1/s] or auto"),
        (["--detection-study", str(path), "--detection-gain", "70"], "no pair tuned at k_o = 70 1/s (gains: 5, 200)"),
    ):
        assert main([*argv, *extra, "--out", str(tmp_path / "bad")]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "bad" / "reaction_study.json").exists()
