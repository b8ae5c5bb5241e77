"""``--reaction-setting KEY=VALUE`` of the collision commands and ``reaction-study``: parsed into ReactionSettings
(whose own checks name a bad value), carried into the controller the run uses, and recorded in the summaries."""

from __future__ import annotations

import json

import pytest

from reflexarm._cli.common import changed_settings, reaction_settings_of
from reflexarm.cli import main
from reflexarm.control import ReactionSettings
from reflexarm.errors import ConfigError


def test_key_value_pairs_become_reaction_settings_and_bad_ones_are_named():
    assert reaction_settings_of(None) is None and reaction_settings_of([]) is None
    s = reaction_settings_of(["retract_distance=0.1, max_retract_time=0.4", "isolation_points_per_tick=8"])
    assert s == ReactionSettings(retract_distance=0.1, max_retract_time=0.4, isolation_points_per_tick=8)
    assert changed_settings(s) == " (retract_distance=0.1, max_retract_time=0.4, isolation_points_per_tick=8)"
    assert changed_settings(ReactionSettings()) == "" and changed_settings(None) == ""
    for text, value in (("true", True), ("False", False), ("1", True), ("no", False)):
        assert reaction_settings_of([f"retract_waits_for_estimate={text}"]) == ReactionSettings(
            retract_waits_for_estimate=value
        )
    for bad, message in (
        (["retract_distance"], "expects KEY=VALUE, KEY one of: brake_time, brake_duration"),
        (["retract_dist=0.1"], "got 'retract_dist=0.1'"),
        (["brake_time=fast"], "--reaction-setting brake_time must be a number; got 'fast'"),
        (["isolation_points_per_tick=2.5"], "--reaction-setting isolation_points_per_tick must be an integer"),
        (["brake_time=-1"], "ReactionSettings.brake_time must be a positive number"),
        (["max_retract_time=nan"], "ReactionSettings.max_retract_time must be a positive number"),
        (["retract_waits_for_estimate=maybe"], "--reaction-setting retract_waits_for_estimate must be true or false"),
    ):
        with pytest.raises(ConfigError, match=None) as err:
            reaction_settings_of(bad)
        assert message in str(err.value)


def test_the_reaction_study_runs_with_the_settings_and_records_them(tmp_path, capsys):
    """A brake that holds from its first tick (brake_duration 1 ms) and one that damps 0.25 s: the runs differ,
    and the study's conditions and console line name the changed setting."""
    common = ["reaction-study", "--arm", "panda", "--reactions", "brake", "--scenarios", "demo"]
    assert main([*common, "--out", str(tmp_path / "default")]) == 0
    assert main([*common, "--reaction-setting", "brake_duration=0.001", "--out", str(tmp_path / "short")]) == 0
    assert "reaction settings (brake_duration=0.001)" in capsys.readouterr().err
    default, short = (json.loads((tmp_path / k / "reaction_study.json").read_text()) for k in ("default", "short"))
    assert "reaction_settings" not in default["conditions"]
    assert short["conditions"]["reaction_settings"]["brake_duration"] == 0.001
    (d,), (s,) = default["rows"], short["rows"]
    assert d["detected_s"] == s["detected_s"] is not None  # the same run up to detection
    assert d["kinetic_energy_ratio"] != s["kinetic_energy_ratio"]  # then another reaction
    assert main([*common, "--reaction-setting", "brake_time=0", "--out", str(tmp_path / "bad")]) != 0
    assert "ReactionSettings.brake_time must be a positive number; got 0.0" in capsys.readouterr().err
    assert not (tmp_path / "bad" / "reaction_study.json").exists()  # refused before any run


def test_a_collision_command_passes_the_settings_to_its_controller(tmp_path, capsys):
    out = tmp_path / "link"
    argv = ["simulate", "link-collision", "--out", str(out), "--quiet", "--reaction", "retract",
            "--reaction-setting", "retract_distance=0.08"]  # fmt: skip
    assert main(argv) == 0
    assert "reaction retract (retract_distance=0.08)" in capsys.readouterr().err
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["detection"]["reaction_settings"]["retract_distance"] == 0.08
