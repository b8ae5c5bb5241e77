"""Coverage before trust (issue 17 item 5) and the threshold plumbing of issue 18 item 8: ``tune-thresholds``
reports what the logs covered of each joint, refuses levels for a joint that did not move (or marks them with
``--allow-unmoved``), stores the coverage, and ``detect`` warns on a motion outside it; without ``--robot`` the
model file's robot is taken and the model error line says what it compares."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from impact_logs import impact_log
from reflexarm.cli import main
from reflexarm.detect import check_coverage, measure_coverage
from reflexarm.logs import save_log
from reflexarm.robots import load_robot

ROBOT = "iiwa14"
STILL = 6  # 0-based: the wrist joint that does not move in the tuning log


@pytest.fixture(scope="module")
def iiwa():
    return load_robot(ROBOT)


def _still_wrist(log):
    """The log with joint 7 held at 0.3 rad (noise only on its velocity), as a log whose wrist never moved."""
    q, dq = log.q.copy(), log.dq.copy()
    q[:, STILL] = 0.3
    dq[:, STILL] = np.random.default_rng(0).normal(0.0, 2e-3, q.shape[0])
    return replace(log, q=q, dq=dq, source="still_wrist")


def test_coverage_is_the_logs_span_and_speed(iiwa):
    log = impact_log(iiwa, rate_hz=100.0, duration_s=10, seed=1).log
    cov = measure_coverage([log.q[:500], log.q[500:]], [log.dq[:500], log.dq[500:]], iiwa)
    np.testing.assert_allclose([c.q_min for c in cov], log.q.min(axis=0), atol=0)
    np.testing.assert_allclose([c.q_max for c in cov], log.q.max(axis=0), atol=0)
    np.testing.assert_allclose([c.speed for c in cov], np.abs(log.dq).max(axis=0), atol=0)
    width = iiwa.upper_limit - iiwa.lower_limit
    np.testing.assert_allclose([c.range_share for c in cov], (log.q.max(0) - log.q.min(0)) / width, rtol=1e-12)
    assert all(c.moved for c in cov)
    still = measure_coverage([_still_wrist(log).q], [_still_wrist(log).dq], iiwa)
    assert [c.moved for c in still] == [True] * 6 + [False]
    # the same log is inside its own coverage; the moving wrist is outside the still one's, from its first sample
    assert check_coverage(log.t, log.q, log.dq, cov) == []
    outside = check_coverage(log.t, log.q, log.dq, still)
    assert [o.joint for o in outside] == [STILL] and outside[0].share > 0.9 and not outside[0].moved_in_tuning


def test_unmoved_joints_are_refused_or_marked_and_detect_warns(iiwa, tmp_path, capsys):
    log = _still_wrist(impact_log(iiwa, rate_hz=100.0, duration_s=120, seed=1).log)
    path = save_log(log, tmp_path / "still.parquet")
    out = tmp_path / "thr"
    args = (f"tune-thresholds {path} --robot {ROBOT} --detection-observer-gain 100 --rate 1 --contact-rate 600 "
            f"--allow-extrapolation --no-figure --out {out}").split()  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "joint(s) 7 did not move in the logs" in err and "--allow-unmoved" in err
    assert "joint 7 (iiwa_joint_7): q in [0.300, 0.300] (0 % of its range)" in err
    assert not (out / "thresholds.json").exists()
    assert main([*args, "--allow-unmoved"]) == 0
    printed = capsys.readouterr().out
    assert "coverage of the logs" in printed and "NOT MOVED" in printed
    doc = json.loads((out / "thresholds.json").read_text())
    assert [c["moved"] for c in doc["coverage"]] == [True] * 6 + [False]
    assert doc["joints"][STILL]["moved"] is False and doc["observer"]["observer_discretization"] == "exact"
    # detect: a log that moves the wrist is flagged; the tuning log itself is not
    moving = save_log(impact_log(iiwa, rate_hz=100.0, duration_s=10, seed=2).log, tmp_path / "moving.parquet")
    for name, file in (("moving", moving), ("still", path)):
        assert main(["detect", str(file), "--robot", ROBOT, "--threshold", str(out / "thresholds.json"),
                     "--no-figure", "--no-isolation", "--out", str(tmp_path / name)]) == 0  # fmt: skip
        printed = capsys.readouterr().out
        flagged = "joint 7 (iiwa_joint_7) (a joint that did not move in the tuning logs) is outside" in printed
        assert flagged == (name == "moving"), printed


@pytest.fixture(scope="module")
def model_file(iiwa, tmp_path_factory) -> Path:
    """A model file for iiwa14 holding a +-10 % perturbed model written as an identification result (physically
    consistent, so the controller can use it), in its own folder."""
    from reflexarm.ident import compute_base_parameters, save_identified_model
    from reflexarm.ident.estimation.identify import DynamicsIdentification, FrictionParameters
    from reflexarm.robots import perturb_model

    pert = perturb_model(iiwa, 0.1, seed=5)
    base = compute_base_parameters(iiwa)
    pi = pert.inertial_parameters()
    res = DynamicsIdentification(
        method="sequential", robot_name=iiwa.name, joint_names=tuple(iiwa.joint_names), base=base,
        beta_b=base.base_from_standard(pi), friction=FrictionParameters.from_model(pert.friction),
        beta_std=np.zeros(base.n_base), noise_variance=np.ones(iiwa.n), condition_number=1.0, n_samples=1,
        residual_rms=np.zeros(iiwa.n), physical_parameters=pi,
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return save_identified_model(res, iiwa, tmp_path_factory.mktemp("model") / "model.json")


def test_without_robot_the_model_files_robot_is_used_and_the_error_line_says_what_it_compares(
    iiwa, model_file, tmp_path, capsys
):
    log = save_log(impact_log(iiwa, rate_hz=100.0, duration_s=120, seed=1).log, tmp_path / "free.parquet")
    args = (f"tune-thresholds {log} --model {model_file} --detection-observer-gain 100 --rate 1 --contact-rate 600 "
            f"--allow-extrapolation --no-figure --out {tmp_path / 'thr'}").split()  # fmt: skip
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "robot 'iiwa14' from model.json (give --robot to use another file)" in err, err
    assert ("achieved model error: the identified model model.json against the robot file 'iiwa14' (its nominal "
            "parameters; not against the arm that recorded the logs") in err  # fmt: skip
    doc = json.loads((tmp_path / "thr" / "thresholds.json").read_text())
    assert [j["name"] for j in doc["joints"]] == list(iiwa.joint_names)
