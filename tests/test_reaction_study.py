"""The reaction study: its arms, its rows, a refused reaction, the files it writes, and the physics it must
show (an arm without joint friction or damping moves on after a gravity-compensation reaction at least as
much as the same arm with its friction)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.experiments.reaction_study import (
    KE_RATIO_GOAL,
    SCENARIOS,
    STUDY_ARMS,
    StudyArm,
    run_reaction_study,
    study_arm,
)
from reflexarm.experiments.rest_floor import floor_verdict
from reflexarm.sim import SensorNoise


def test_study_arms_load(tmp_path):
    for name in STUDY_ARMS:
        arm = study_arm(name, tmp_path)
        assert isinstance(arm, StudyArm) and arm.name == name
    assert study_arm("ur_like", tmp_path).robot.n == 6
    assert study_arm("iiwa14_frictionless").plant_friction == "none"
    assert study_arm("iiwa14").plant_friction == "file"
    with pytest.raises(ConfigError, match="unknown study arm 'kuka'; choose one of: atlas_v5_left_arm, panda, iiwa14"):
        study_arm("kuka")


def test_bad_scenarios_and_reactions_are_named():
    with pytest.raises(ConfigError, match="unknown scenario 'push'; choose from: demo, link"):
        run_reaction_study(["iiwa14"], ["gravity"], ["push"])
    with pytest.raises(ConfigError, match="no reaction to study"):
        run_reaction_study(["iiwa14"], [], SCENARIOS)


@pytest.fixture(scope="module")
def link_study():
    return run_reaction_study(["iiwa14", "iiwa14_frictionless"], ["gravity", "hover"], ["link"])


def test_rows_and_a_refused_reaction(link_study, tmp_path):
    rows = link_study.rows
    assert [(r["arm"], r["reaction"]) for r in rows] == [
        ("iiwa14", "gravity"),
        ("iiwa14", "hover"),
        ("iiwa14_frictionless", "gravity"),
        ("iiwa14_frictionless", "hover"),
    ]
    for r in rows:
        if r["reaction"] == "hover":  # the controller refuses it, naming its choices; the study goes on
            assert r["error"] is not None and "unknown reaction 'hover'" in r["error"]
            assert link_study.outcome(r["arm"], "link", "hover") is None
        else:
            assert r["error"] is None and r["contact_class"] == "link" and r["detected_s"] is not None
            assert r["detected_s"] >= r["contact_s"]
            assert r["run"] == f"{r['arm']}/link/gravity"
    # each detected run carries its rest floor (the same posture for every reaction of an arm and scenario)
    floors = {r["arm"]: r["rest_floor_q95_J"] for r in rows if r["error"] is None}
    for r in rows:
        if r["error"] is None:
            assert r["rest_floor_median_J"] <= r["rest_floor_q95_J"] <= r["rest_floor_max_J"]
            assert r["ke_floor_verdict"] == floor_verdict(r)
    assert floors["iiwa14_frictionless"] > floors["iiwa14"]  # nothing but the controller damps the trembling
    files = link_study.write(tmp_path)
    doc = json.loads(files["json"].read_text())
    assert doc["conditions"]["model_error"] == 0.1 and doc["conditions"]["threshold_Nm"] == 11.0
    assert len(doc["rows"]) == 4
    lines = files["csv"].read_text().splitlines()
    assert lines[0].startswith("arm,scenario,reaction,plant_friction,error,run,") and len(lines) == 5


def test_rest_floors_can_be_left_out():
    (row,) = run_reaction_study(["iiwa14_frictionless"], ["brake"], ["link"], rest_floors=False).rows
    assert row["error"] is None and row["detected_s"] is not None
    assert "rest_floor_q95_J" not in row and "ke_floor_verdict" not in row


def test_without_friction_the_arm_moves_on_at_least_as_far(link_study):
    """Same arm, controller, noise and contact; the plant without friction and damping dissipates less, so
    after the gravity-compensation reaction it keeps more kinetic energy and moves at least as far."""
    a = link_study.outcome("iiwa14", "link", "gravity")
    b = link_study.outcome("iiwa14_frictionless", "link", "gravity")
    assert a is not None and b is not None
    assert b.moved_after_detection_m >= a.moved_after_detection_m
    assert b.kinetic_energy_after_J >= a.kinetic_energy_after_J
    assert np.isfinite(b.peak_speed_ratio)


@pytest.mark.parametrize("scenario", ["demo", "link_held"])
def test_the_reaction_acts_from_the_detecting_tick(scenario):
    """iiwa14, brake and retract: the contact never exceeds its level at detection afterwards, and the retract ends
    >= 2 cm from the contact (issue 15). With the reaction one tick late (the core before 7a2d90e) the tick after
    detection still carried the old law's push: 21.9 -> 24.7 N (demo) and 16.9 -> 17.8 Nm (held stick)."""
    study = run_reaction_study([study_arm("iiwa14")], ["brake", "retract"], [scenario])
    for reaction in ("brake", "retract"):
        o = study.outcome("iiwa14", scenario, reaction)
        assert o is not None and o.detected_s is not None
        if scenario == "demo":
            at, peak = o.force_at_detection_N, o.peak_force_after_detection_N
        else:
            at, peak = o.external_torque_at_detection_Nm, o.peak_external_torque_after_detection_Nm
        assert at is not None and peak is not None and peak <= at, (reaction, at, peak)
        assert not o.recontact
    away = study.outcome("iiwa14", scenario, "retract").away_at_end_m
    assert away is not None and away >= 0.02


#: [J] The held-stick retract's peak kinetic energy after detection, without noise: 1.04 J (iiwa14) and 1.10 J
#: (UR5-like) with the retract along J^T f, 0.18 J and 0.07 J along the admittance M^-1 J^T f; the bound sits between
#: with a factor >= 1.7 to either side.
HELD_RETRACT_PEAK_KE_J = 0.3


def test_the_retract_moves_the_arm_by_its_admittance(tmp_path):
    """Held stick, retract, no noise (deterministic): the joint motion M(q)^-1 J^T f (the velocity an impulse of the
    contact force gives the free arm) moves the light joints more than the heavy ones, so the retract carries less
    kinetic energy. Along J^T f (the core before it, 21f0aad) the iiwa14 and the UR5-like arm (whose stick only joint
    1 feels, so that the retract must turn the base) peaked at 1.04 and 1.10 J (0.18 and 0.07 J now; Atlas 1.41 ->
    0.74 J); every retract still ends >= 2 cm from the contact, and Atlas' kinetic energy 0.5 s after detection is
    below 1 % of its value at detection (0.48 % before, 0.001 % now; 2.3 % before the faster isolation of 21f0aad)."""
    arms = [study_arm("atlas_v5_left_arm"), study_arm("iiwa14"), study_arm("ur_like", tmp_path)]
    study = run_reaction_study(arms, ["retract"], ["link_held"], noise=SensorNoise.none())
    for arm in ("atlas_v5_left_arm", "iiwa14", "ur_like"):
        o = study.outcome(arm, "link_held", "retract")
        assert o is not None and o.detected_s is not None and not o.recontact
        assert o.away_at_end_m is not None and o.away_at_end_m >= 0.02, (arm, o.away_at_end_m)
        assert o.peak_kinetic_energy_after_detection_J is not None
        if arm == "atlas_v5_left_arm":
            assert o.kinetic_energy_ratio is not None and o.kinetic_energy_ratio < KE_RATIO_GOAL
        else:
            assert o.peak_kinetic_energy_after_detection_J < HELD_RETRACT_PEAK_KE_J, arm
