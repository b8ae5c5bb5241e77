"""``reflexarm reaction-study``: one arm, scenario and reaction runs and writes its table, CSV, JSON and
figure; bad arguments are refused before any run with a message naming the value and the choices."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from reflexarm.cli import main
from reflexarm.experiments.reaction_study import (
    KE_RATIO_GOAL,
    PEAK_RATIO_GOAL,
    ReactionStudy,
    reaction_measures,
    reaction_study_figure,
)


@pytest.fixture(scope="module")
def one_run(tmp_path_factory):
    """The study on the iiwa14 without joint friction, link push, brake (one run, ~2 s)."""
    out = tmp_path_factory.mktemp("reaction_study")
    argv = ["reaction-study", "--arms", "iiwa14_frictionless", "--scenarios", "link", "--reactions", "brake"]
    return out, argv + ["--out", str(out)]


def test_one_arm_scenario_reaction_runs_and_writes_its_files(one_run, capsys):
    out, argv = one_run
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "[1/1," in captured.err and "iiwa14_frictionless / link / brake" in captured.err  # progress
    header, row = captured.out.splitlines()[:2]
    for column in ("at detection -> peak after", "KE(+0.5 s)/KE(det)", "moved [m]", "peak speed/limit", "guard"):
        assert column in header
    assert row.split()[:3] == ["iiwa14_frictionless", "link", "brake"]
    for name in ("reaction_study.csv", "reaction_study.json", "reaction_study.png"):
        assert (out / name).is_file(), name
        assert f"{out / name}" in captured.out
    doc = json.loads((out / "reaction_study.json").read_text())
    (r,) = doc["rows"]
    assert (r["arm"], r["scenario"], r["reaction"], r["error"]) == ("iiwa14_frictionless", "link", "brake", None)
    assert r["plant_friction"] == "none" and r["detected_s"] is not None and isinstance(r["guard"], str)
    assert doc["conditions"]["model_error"] == 0.1 and doc["conditions"]["seed"] == 0
    with open(out / "reaction_study.csv", newline="") as fh:
        (line,) = list(csv.DictReader(fh))
    assert line["arm"] == "iiwa14_frictionless" and float(line["kinetic_energy_ratio"]) == r["kinetic_energy_ratio"]
    # the printed level is the link class's external torque at detection -> its peak after
    m = reaction_measures(r)
    assert m["level_unit"] == "Nm" and m["level_at_detection"] == r["external_torque_at_detection_Nm"]
    assert m["level_text"] in row
    assert "away at end [m]" in header and f"{r['away_at_end_m']:.3f}" in row
    assert doc["conditions"]["noise"] == "paper"
    # the rest floor: a column, and the summary counts the misses of the 1 % bar and those at the floor
    assert "rest floor [J]" in header and f"{r['rest_floor_q95_J']:.2g}" in row
    miss = int(r["kinetic_energy_ratio"] >= KE_RATIO_GOAL)
    at_floor = int(miss and r["kinetic_energy_after_J"] <= r["rest_floor_q95_J"])
    assert f"{miss} run(s) miss the 1 % bar, {at_floor} of them at or below their rest floor" in captured.out


def test_noise_none_runs_without_sensor_noise(tmp_path, capsys):
    out = tmp_path / "quiet"
    argv = ["reaction-study", "--arms", "iiwa14_frictionless", "--scenarios", "link", "--reactions", "brake"]
    assert main([*argv, "--noise", "none", "--out", str(out)]) == 0
    assert "no sensor noise" in capsys.readouterr().err
    doc = json.loads((out / "reaction_study.json").read_text())
    assert doc["conditions"]["noise"] != "paper" and "dq=0.0" in doc["conditions"]["noise"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--arms", "kuka"], "--arms: unknown 'kuka'; choose from: atlas_v5_left_arm, panda, iiwa14, ur_like"),
        (["--arms", ","], "--arms needs at least one name; got ','"),
        (["--scenarios", "push"], "--scenarios: unknown 'push'; choose from: demo, link"),
        (["--reactions", "brake,hover"], "--reactions: unknown 'hover'; choose from: gravity, brake, retract"),
        (["--model-error", "120"], "--model-error must be a percentage in [0, 100); got 120"),
        (["--model-error", "nan"], "--model-error must be a percentage in [0, 100); got nan"),
        (["--seed", "-1"], "--seed must be a non-negative integer; got -1"),
    ],
)
def test_bad_arguments_are_named_before_any_run(tmp_path, capsys, args, message):
    assert main(["reaction-study", *args, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert f"reflexarm reaction-study: error: {message}" in err
    assert not (tmp_path / "x").exists()  # refused before anything ran or was written


def test_the_figure_has_a_bar_per_reaction_and_the_issue_lines():
    rows = [
        {
            "arm": a,
            "scenario": s,
            "reaction": r,
            "error": None,
            "contact_class": "link",
            "detected_s": 1.0,
            "external_torque_at_detection_Nm": 20.0,
            "peak_external_torque_after_detection_Nm": 20.0 * k,
            "kinetic_energy_ratio": 0.001 * k,
            "recontact": False,
        }
        for a in ("panda", "iiwa14")
        for s in ("demo", "link")
        for k, r in enumerate(("brake", "retract"), 1)
    ]
    fig = reaction_study_figure(ReactionStudy(rows=rows, conditions={"model_error": 0.1, "seed": 0}))
    assert isinstance(fig, Figure)
    (top_demo, top_link, bottom_demo, bottom_link) = fig.axes[:4]
    for ax, goal in ((top_demo, KE_RATIO_GOAL), (bottom_link, PEAK_RATIO_GOAL)):
        assert any(tuple(ln.get_ydata()) == (goal, goal) for ln in ax.get_lines())
    heights = sorted(p.get_height() for p in bottom_demo.patches)
    np.testing.assert_allclose(heights, [1.0, 1.0, 2.0, 2.0])  # peak / at detection, per arm and reaction
    np.testing.assert_allclose(sorted(p.get_height() for p in top_link.patches), [0.001, 0.001, 0.002, 0.002])


def test_the_cli_defaults_are_the_study_s():
    # the parser carries copies of the study's names so that building it imports no experiment
    from reflexarm._cli import reaction_study as cli
    from reflexarm.experiments import reaction_study as study

    assert (cli.STUDY_ARMS, cli.STUDY_REACTIONS, cli.SCENARIOS) == (
        study.STUDY_ARMS, study.STUDY_REACTIONS, study.SCENARIOS
    )  # fmt: skip
