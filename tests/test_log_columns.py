"""Table logs as robots export them: joint-named columns, the JointState layout, 0-based numbering, a
column mapping; extra columns ignored with a note; a missing signal names what was looked for."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from log_exports import write_joint_state_csv
from reflexarm.cli import main
from reflexarm.errors import ConfigError, DataError
from reflexarm.ident import RobotLog, load_log, plan_friction_experiment
from reflexarm.logs import parse_column_mapping

NAMES = ["shoulder_pan", "shoulder_lift", "elbow"]


def _log(n=300):
    t = np.arange(n) * 1e-3
    w = 2 * np.pi * np.array([0.5, 0.8, 1.1])
    q = np.sin(np.outer(t, w))
    dq = np.cos(np.outer(t, w)) * w
    tau = np.random.default_rng(0).normal(size=(n, 3))
    wrench = np.random.default_rng(1).normal(size=(n, 6))
    return RobotLog(t, q, dq, tau, wrench=wrench, source="x")


def _frame(log, pattern_q, pattern_dq, pattern_tau, time="t"):
    cols = {time: log.t}
    for j, name in enumerate(NAMES):
        cols[pattern_q.format(joint=name, i=j + 1, i0=j)] = log.q[:, j]
        cols[pattern_dq.format(joint=name, i=j + 1, i0=j)] = log.dq[:, j]
        cols[pattern_tau.format(joint=name, i=j + 1, i0=j)] = log.tau[:, j]
    return pd.DataFrame(cols)


def _same(back, log):
    for name in ("q", "dq", "tau"):
        np.testing.assert_array_equal(getattr(back, name), getattr(log, name), err_msg=name)


@pytest.mark.parametrize(
    ("pq", "pdq", "ptau", "time"),
    [
        ("position_{joint}", "velocity_{joint}", "effort_{joint}", "time"),
        ("{joint}/position", "{joint}/velocity", "{joint}/effort", "timestamp"),
        ("{joint}_pos", "{joint}_vel", "{joint}_torque", "t"),
        ("/joint_states/{joint}/position", "/joint_states/{joint}/velocity", "/joint_states/{joint}/effort", "__time"),
    ],
)
def test_joint_named_columns_are_mapped_by_name(tmp_path, pq, pdq, ptau, time):
    log = _log()
    df = _frame(log, pq, pdq, ptau, time)
    df = df[[df.columns[0], *reversed(df.columns[1:])]]  # column order must not matter
    p = tmp_path / "named.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    back = load_log(p, joint_names=NAMES)
    _same(back, log)
    # the note spells the columns as they are in the file (not the normalized form they were matched in)
    assert f"named.csv: position from joint-named columns {pq.format(joint='<joint>')}" in back.notes
    assert f"named.csv: measured torque from joint-named columns {ptau.format(joint='<joint>')}" in back.notes


def test_joint_state_layout_is_mapped_by_name_row_by_row(tmp_path):
    log = _log()
    p = write_joint_state_csv(log, tmp_path / "js.csv", NAMES)
    back = load_log(p, joint_names=NAMES)
    _same(back, log)
    assert "js.csv: JointState rows: the joint order changes between rows (2 orders), mapped per row" in back.notes


def test_joint_state_layout_without_names_is_the_model_order_and_says_so(tmp_path):
    log = _log()
    df = _frame(log, "position[{i0}]", "velocity[{i0}]", "effort[{i0}]")
    p = tmp_path / "js.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    back = load_log(p, n_joints=3)
    _same(back, log)
    assert any("without name columns: element k taken as joint k + 1" in n for n in back.notes)


def test_zero_based_numbered_columns_are_recognized_and_said_so(tmp_path):
    log = _log()
    p = tmp_path / "zero.csv"
    _frame(log, "q_{i0}", "dq_{i0}", "tau_{i0}").to_csv(p, index=False, float_format="%.17g")
    back = load_log(p, n_joints=3)
    _same(back, log)
    assert "zero.csv: columns q_0..q_2 numbered from 0: taken as joints 1..3" in back.notes


def test_wrench_under_ros_names(tmp_path):
    log = _log()
    df = _frame(log, "q_{i}", "dq_{i}", "tau_{i}")
    for k, axis in enumerate(("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")):
        df[f"wrench.{axis}"] = log.wrench[:, k]
    p = tmp_path / "w.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    np.testing.assert_array_equal(load_log(p).wrench, log.wrench)


def test_explicit_mapping_wins_and_is_checked(tmp_path):
    log = _log()
    df = _frame(log, "pos{i}", "vel{i}", "trq_{joint}", time="clock_ms")
    df["clock_ms"] = np.arange(len(df)) * 1  # integer milliseconds
    p = tmp_path / "own.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    mapping = parse_column_mapping("t=clock_ms, q=pos{i}, dq=vel{i}, tau=trq_{joint}")
    back = load_log(p, joint_names=NAMES, columns=mapping)
    _same(back, log)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=1e-15)  # ms integers scaled by 1e-3
    assert "own.csv: position from columns 'pos{i}' (mapping)" in back.notes
    with pytest.raises(DataError, match=r"own\.csv: column\(s\) 'speed1', 'speed2', 'speed3' of the mapping dq="):
        load_log(p, joint_names=NAMES, columns={**mapping, "dq": "speed{i}"})
    with pytest.raises(
        ConfigError,
        match=r"unknown column mapping key 'qd'; keys: t, q, dq, tau, ddq, current, wrench \(cur = current\)",
    ):
        parse_column_mapping("qd=vel{i}")
    with pytest.raises(
        ConfigError, match=r"q='pos\{n\}': unknown placeholder \{n\}; allowed: \{joint\}, \{i\}, \{i0\}"
    ):
        parse_column_mapping("q=pos{n}")
    with pytest.raises(ConfigError, match=r"entry 'q' is not KEY=SPEC"):
        parse_column_mapping("q")


def test_a_missing_signal_names_what_was_looked_for(tmp_path):
    log = _log()
    df = _frame(log, "position_{joint}", "velocity_{joint}", "current_{joint}")
    p = tmp_path / "m.csv"
    df.to_csv(p, index=False)
    with pytest.raises(DataError, match=r"m\.csv: no measured torque columns: looked for tau_1\.\.tau_3, "
                       r"tau_0\.\.tau_2, effort_shoulder_pan, .*effort\.0 \(JointState layout\) "
                       r"\(for joint 1, 'shoulder_pan'; likewise the others\); found: t, ") as info:  # fmt: skip
        load_log(p, joint_names=NAMES)
    assert info.value.column[:3] == ("tau_1..tau_3", "tau_0..tau_2", "effort_shoulder_pan")
    assert info.value.expected == tuple(df.columns)


def test_a_joint_missing_from_named_columns_is_named(tmp_path):
    df = _frame(_log(), "position_{joint}", "velocity_{joint}", "effort_{joint}").drop(columns=["velocity_elbow"])
    p = tmp_path / "m.csv"
    df.to_csv(p, index=False)
    with pytest.raises(DataError, match=r"m\.csv: velocity columns 'velocity_<joint>' found for 2 of the 3 joints; "
                       r"missing for joint\(s\) 'elbow' \(looked for 'velocity_elbow'\)") as info:  # fmt: skip
        load_log(p, joint_names=NAMES)
    assert (info.value.source, info.value.joint, info.value.column) == ("m.csv", "elbow", "velocity_elbow")


def test_two_columns_matching_one_name_are_refused(tmp_path):
    df = _frame(_log(), "/left/{joint}/position", "{joint}/velocity", "{joint}/effort")
    df["/right/elbow/position"] = 0.0
    p = tmp_path / "two.csv"
    df.to_csv(p, index=False)
    with pytest.raises(DataError, match=r"two\.csv: 2 columns match 'elbow.position': '/left/elbow/position', "
                       r"'/right/elbow/position'; name the one to use with a column mapping"):  # fmt: skip
        load_log(p, joint_names=NAMES)


def test_cli_reads_joint_named_columns_with_a_mapping_and_prints_the_notes(tmp_path, capsys, atlas):
    """identify friction --run with --columns and --time-unit: the reader's notes are printed."""
    from reflexarm.ident import BatchRegressor, FrictionParameters

    plan = plan_friction_experiment(atlas, 0, speeds=(0.2, 0.5, 1.0))
    t = np.arange(0.0, plan.duration, 1e-3)
    q, dq, ddq = plan.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    cols = {"stamp": np.round(t * 1e6).astype(np.int64) + 5_000_000, "seq": np.arange(t.size)}
    for j, name in enumerate(atlas.joint_names):
        cols |= {f"p_{name}": q[:, j], f"v_{name}": dq[:, j], f"e_{name}": tau[:, j]}
    p = tmp_path / "runs.csv"
    pd.DataFrame(cols).to_csv(p, index=False, float_format="%.17g")
    out = tmp_path / "fr"
    args = ["identify", "friction", "--run", f"1={p}", "--columns", "t=stamp,q=p_{joint},dq=v_{joint},tau=e_{joint}"]
    assert main([*args, "--time-unit", "us", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "log: runs.csv: ignored 1 column(s) no signal needs: seq" in text
    assert (
        "log: runs.csv: time stamps (stamp): in us (given); made relative to the first sample (subtracted 5000000 us"
        in text
    )
    doc = json.loads((out / "friction.json").read_text())
    # exact data: the same fit as the schema log gives in test_ident_cli (2.0 Nm, 1.3 Nms/rad)
    assert doc["coulomb"][0] == pytest.approx(2.0, rel=0.01) and doc["viscous"][0] == pytest.approx(1.3, rel=0.01)


def test_ros1_rostopic_export_layout(tmp_path):
    """``rostopic echo -p``: %time (receive time, ns), field.header.stamp (ns), field.name0, field.position0 ..."""
    log = _log()
    stamps = 1_795_435_200_000_000_000 + np.round(log.t * 1e9).astype(np.int64)
    cols: dict[str, object] = {"%time": stamps + 250_000, "field.header.seq": np.arange(len(log))}
    cols |= {"field.header.stamp": stamps, "field.header.frame_id": "base"}
    cols |= {f"field.name{k}": name for k, name in enumerate(NAMES)}
    for field, arr in (("position", log.q), ("velocity", log.dq), ("effort", log.tau)):
        cols |= {f"field.{field}{k}": arr[:, k] for k in range(3)}
    p = tmp_path / "ros1.csv"
    pd.DataFrame(cols).to_csv(p, index=False, float_format="%.17g")
    back = load_log(p, joint_names=NAMES)
    _same(back, log)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=1e-15)  # integer ns made relative
    assert "ros1.csv: time from column 'field.header.stamp'" in back.notes  # the header stamp, not %time
    assert any(
        "ignored 3 column(s) no signal needs: %time, field.header.seq, field.header.frame_id" in n for n in back.notes
    )


def test_parquet_array_columns_of_a_bag_to_dataframe_export(tmp_path):
    """One row per JointState message with ``name``/``position``/.. as arrays (Parquet lists), the header
    stamp as sec + nanosec; a gripper's shorter messages in between."""
    log = _log()
    stamps = 1_795_435_200_000_000_000 + np.round(log.t * 1e9).astype(np.int64)
    rows = []
    for i in range(len(log)):
        order = [2, 0, 1] if i % 3 else [0, 1, 2]
        if i % 50 == 0:
            rows.append({"header.stamp.sec": int(stamps[i] // 10**9), "header.stamp.nanosec": int(stamps[i] % 10**9),
                         "name": ["finger"], "position": np.array([0.04]), "velocity": np.zeros(0),
                         "effort": np.zeros(0)})  # fmt: skip
        rows.append({"header.stamp.sec": int(stamps[i] // 10**9), "header.stamp.nanosec": int(stamps[i] % 10**9),
                     "name": [NAMES[j] for j in order], "position": log.q[i, order], "velocity": log.dq[i, order],
                     "effort": log.tau[i, order]})  # fmt: skip
    p = tmp_path / "df.parquet"
    pd.DataFrame(rows).to_parquet(p)
    back = load_log(p, joint_names=NAMES)
    _same(back, log)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=1e-15)
    text = "\n".join(back.notes)
    assert "df.parquet: array column(s) name, position, velocity, effort expanded to one column per element" in text
    assert "left out 6 row(s) that hold none of the arm's joints (joints finger: not in the arm)" in text


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_positions_work_in_files_with_a_header_and_take_a_scale(tmp_path, suffix):
    """Positions count the file's columns from 0 as they stand (header or not); the wrench by position; a
    scale per entry; the current alias 'cur'."""
    log = _log()
    df = _frame(log, "a{i}", "b{i}", "c{i}", time="clock")  # t, a1, b1, c1, a2, b2, c2, ...
    for k in range(6):
        df[f"w{k}"] = 1e3 * log.wrench[:, k]  # in mN / mNm
    p = tmp_path / f"pos{suffix}"
    if suffix == ".csv":
        df.to_csv(p, index=False, float_format="%.17g")
    else:
        df.to_parquet(p, index=False)
    mapping = parse_column_mapping("t=0,q=1:10:3,dq=2:10:3,tau=3:10:3,wrench=10:16*0.001")
    back = load_log(p, joint_names=NAMES, columns=mapping)
    _same(back, log)
    np.testing.assert_allclose(back.wrench, log.wrench, rtol=1e-15, atol=1e-15)
    assert f"pos{suffix}: position from columns 1:10:3 by position (a1, a2, a3)" in back.notes
    assert parse_column_mapping("cur=13:19") == {"current": "13:19"}
    with pytest.raises(ConfigError, match=r"column mapping key 'q' given twice"):
        parse_column_mapping("q=1:4,q=4:7")
