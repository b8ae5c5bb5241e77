"""One identification log exported four ways (plain CSV; ns epoch stamps with joint-named and extra columns;
MCAP bag; rosbag2 sqlite3 bag; each with the wrist wrench) reads to the same samples, identifies to the same
model and validates."""

from __future__ import annotations

import json

import numpy as np
import pytest

from log_exports import EPOCH_NS, write_bag, write_named_csv
from reflexarm.cli import main
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, load_log, save_log
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.export.model_file import read_identified_model

#: Seconds of log: the shortest that identifies Atlas's 43 base parameters well enough to validate
#: (a consistent model after projection), to keep the four CLI runs short.
DURATION = 6.0
#: The plain CSV's times are decimals (t = k * 1e-3 written with 10 digits); the others are integer ns
#: from an epoch start, made relative and scaled by 1e-9 in float64: equal to within a few ulp of 6 s.
TIME_ATOL = 1e-14
#: The four files hold the same q, dq, tau bit for bit (written from the plain CSV as read back) and
#: times equal to TIME_ATOL. The least-squares estimate moves by about cond(W) * 1e-16 relative (cond of
#: the base regressor ~1e2 here), the consistency projection's optimizer stops at its own tolerance from
#: the same start: 1e-6 relative on the base parameters bounds both with margin, far below what a wrong
#: joint mapping or time scale does (O(1) relative changes). Measured here: identical to the last bit.
MODEL_RTOL = 1e-6


@pytest.fixture(scope="module")
def exports(tmp_path_factory, atlas):
    d = tmp_path_factory.mktemp("exports")
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), atlas.home)
    t = np.arange(0.0, DURATION, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    # a slowly varying wrist wrench [N, Nm], carried through every format; the measured torques hold its
    # joint torque as eq. (14) removes it (tau_m = model - J^T w), so the data stay consistent
    wrench = 2.0 * np.sin(2 * np.pi * np.outer(t, [0.3, 0.5, 0.7, 0.2, 0.4, 0.6]) + np.arange(6))
    tau -= np.stack([atlas.compute_frame_jacobian(qk).T @ wk for qk, wk in zip(q, wrench, strict=True)])
    plain = save_log(RobotLog(t, q, dq, tau, wrench=wrench, source="sim"), d / "plain.csv")
    log = load_log(plain, n_joints=7)  # what the CSV holds (10 significant digits): the others repeat it
    names = list(atlas.joint_names)
    return {
        "plain": plain,
        "named": write_named_csv(log, d / "named.csv", names),
        "mcap": write_bag(log, d / "bag.mcap.d", names, storage="mcap", wrench_topic="/ft"),
        "sqlite3": write_bag(log, d / "bag.db3.d", names, storage="sqlite3", wrench_topic="/ft"),
    }


def test_the_four_exports_read_to_the_same_samples(exports, atlas):
    topic = {"mcap": "/ft", "sqlite3": "/ft"}
    logs = {k: load_log(p, joint_names=atlas.joint_names, wrench_topic=topic.get(k)) for k, p in exports.items()}
    ref = logs["plain"]
    for k, log in logs.items():
        np.testing.assert_allclose(log.t, ref.t, rtol=0, atol=TIME_ATOL, err_msg=k)
        for name in ("q", "dq", "tau", "wrench"):  # the bags' wrench: interpolated at its own stamps
            np.testing.assert_array_equal(getattr(log, name), getattr(ref, name), err_msg=f"{k} {name}")
    assert ref.notes == ()
    named = "\n".join(logs["named"].notes)
    assert f"subtracted {EPOCH_NS} ns = 2026-11-23 12:00:00.000000 UTC, a Unix epoch time" in named
    assert "in ns (inferred: the first stamp 1.79544e+18 is a Unix epoch time in ns, period 1 ms)" in named
    assert "ignored 8 column(s) no signal needs: seq, temperature_l_arm_shz" in named
    for k in ("mcap", "sqlite3"):
        text = "\n".join(logs[k].notes)
        assert "times from the /joint_states header stamps (when the robot sampled)" in text
        assert "left out 600 /joint_states message(s) holding none of the arm's joints" in text
        assert "(joints finger_joint1, finger_joint2: not in the arm)" in text


@pytest.mark.slow  # ~50 s: four identifications with the consistency projection, four validations
def test_the_four_exports_identify_to_the_same_model_and_validate(exports, tmp_path, capsys):
    models = {}
    for k, p in exports.items():
        out = tmp_path / k
        args = ["identify", "dynamics", "--log", str(p), "--split", "0.6", "--method", "combined", "--out", str(out)]
        bag_options = ["--wrench-topic", "/ft"] if k in ("mcap", "sqlite3") else []
        assert main([*args, *bag_options, "--quiet"]) == 0, k
        text = capsys.readouterr().out
        if k != "plain":
            assert "log: " in text, k  # the reader's notes are printed
        models[k] = out / "model_combined.json"
        assert main(["validate", "--model", str(models[k]), "--log", str(p), "--out", str(tmp_path / f"v{k}"),
                     *bag_options, "--quiet"]) == 0, k  # fmt: skip
        assert "pooled RMSE:" in capsys.readouterr().out
    ref, _ = read_identified_model(models["plain"])
    ref_val = json.loads((tmp_path / "vplain" / "validate.json").read_text())["validation"]["pooled_rmse"]
    for k, path in models.items():
        result, _ = read_identified_model(path)
        scale = np.abs(ref.beta_b).max()
        np.testing.assert_allclose(result.beta_b, ref.beta_b, rtol=MODEL_RTOL, atol=MODEL_RTOL * scale, err_msg=k)
        np.testing.assert_allclose(result.friction.coulomb, ref.friction.coulomb, rtol=MODEL_RTOL, atol=1e-9, err_msg=k)
        val = json.loads((tmp_path / f"v{k}" / "validate.json").read_text())["validation"]["pooled_rmse"]
        assert val == pytest.approx(ref_val, rel=MODEL_RTOL), k
