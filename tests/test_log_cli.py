"""The identify CLI and logs: nothing is written before a problem with the logs is found; bags and --joint-topic."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, save_log
from reflexarm.ident.excitation.design import FourierTrajectory


def test_no_model_file_is_written_when_validation_fails_on_the_logs(tmp_path, capsys, atlas):
    """A validation log whose short middle segment (between long gaps) preprocessing drops: scoring the
    model there would interpolate across the gap, so validation fails; it used to fail after the model
    files were written, now before."""
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), atlas.home)
    t = np.arange(0.0, 6.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    ident = save_log(RobotLog(t, q, dq, tau), tmp_path / "ident.csv")
    # keep 0-2 s, five samples at 2.5 s, 3-6 s: gaps of ~0.5 s (> 25 periods) around a 5-sample segment
    keep = (t < 2.0) | ((t >= 2.5) & (t < 2.505)) | (t >= 3.0)
    val = save_log(RobotLog(t[keep], q[keep], dq[keep], tau[keep]), tmp_path / "val.csv")
    out = tmp_path / "out"
    args = ["identify", "dynamics", "--log", str(ident), "--validation-log", str(val), "--method", "combined"]
    code = main([*args, "--no-projection", "--out", str(out), "--quiet"])
    assert code == 2
    assert "val.csv: 5 validation sample(s) fall in a gap of the states" in capsys.readouterr().err
    assert not list(out.glob("*.json")), sorted(p.name for p in out.iterdir())


def test_identify_friction_from_a_bag_with_two_joint_state_topics(tmp_path, capsys, atlas):
    """--joint-topic picks the arm's topic; without it the error lists the bag's topics."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from log_exports import write_bag
    from reflexarm.ident import plan_friction_experiment

    plan = plan_friction_experiment(atlas, 0, speeds=(0.2, 0.5, 1.0))
    t = np.arange(0.0, plan.duration, 1e-3)
    q, dq, ddq = plan.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    one = write_bag(RobotLog(t, q, dq, tau), tmp_path / "one", list(atlas.joint_names), storage="mcap")
    # the same messages on /arm/joint_states, plus a second JointState topic (a gripper's)
    store = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "two"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        arm = writer.add_connection("/arm/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        grip = writer.add_connection("/gripper/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        with AnyReader([one]) as reader:
            for k, (_, stamp, raw) in enumerate(reader.messages()):
                writer.write(arm, stamp, raw)
                if k == 0:
                    writer.write(grip, stamp, raw)
    out = tmp_path / "fr"
    args = ["identify", "friction", "--run", f"1={bag}", "--out", str(out), "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "two: 2 sensor_msgs/msg/JointState topics; choose one with the joint topic (--joint-topic); topics: " in err
    assert main([*args, "--joint-topic", "/arm/joint_states"]) == 0
    text = capsys.readouterr().out
    assert "log: two: times from the /arm/joint_states header stamps (when the robot sampled)" in text
    doc = json.loads((out / "friction.json").read_text())
    # exact data: the fit of the plain log in test_ident_cli (2.0 Nm, 1.3 Nms/rad)
    assert doc["coulomb"][0] == pytest.approx(2.0, rel=0.01) and doc["viscous"][0] == pytest.approx(1.3, rel=0.01)
