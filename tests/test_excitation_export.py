"""The excitation as a sampled trajectory (CSV at a chosen rate), checked against the limits, and the
frequency unit stored in Hz (older rad/s files converted)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_TOOL, write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.errors import ConfigError
from reflexarm.ident.excitation.design import FourierTrajectory, excitation_limits, optimize_excitation
from reflexarm.ident.excitation.export import (
    ExcitationLimitError,
    ExcitationMarginWarning,
    sample_excitation,
    write_excitation_csv,
)
from reflexarm.robots.robot_model import RobotModel

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def six_dof(tmp_path_factory: pytest.TempPathFactory) -> RobotModel:
    return load_robot(write_six_dof_urdf(tmp_path_factory.mktemp("arm")), ee_frame=SIX_DOF_TOOL)


@pytest.fixture(scope="module")
def start(six_dof: RobotModel) -> FourierTrajectory:
    """The seeded, unoptimized excitation (the same on every machine), 0.1 Hz, 5 harmonics."""
    return optimize_excitation(six_dof, base_frequency=2 * np.pi * 0.1, maxiter=0, seed=3).initial


def test_files_store_the_base_frequency_in_hz_and_old_rad_per_s_files_are_converted() -> None:
    old = json.loads((DATA / "atlas_excitation.json").read_text())["trajectory"]
    assert "base_frequency_hz" not in old and old["base_frequency"] == pytest.approx(2 * np.pi * 0.1)
    tr = FourierTrajectory.from_dict(old)
    assert tr.base_frequency_hz == pytest.approx(0.1, rel=1e-15) and tr.period == pytest.approx(10.0, rel=1e-15)
    d = tr.to_dict()
    assert "base_frequency" not in d and d["base_frequency_hz"] == pytest.approx(0.1, rel=1e-15)
    assert d["period_s"] == pytest.approx(10.0, rel=1e-15)
    assert FourierTrajectory.from_dict(d).base_frequency == pytest.approx(tr.base_frequency, rel=1e-15)
    assert FourierTrajectory.from_hz(0.1, tr.a, tr.b, tr.offset).base_frequency == tr.base_frequency


def test_the_sampled_excitation_is_the_trajectory_at_the_rate(six_dof: RobotModel, start: FourierTrajectory,
                                                              tmp_path: Path) -> None:  # fmt: skip
    tr = start.with_periods(2)
    sampled = sample_excitation(tr, six_dof, rate=250.0)
    assert sampled.t.size == 2 * 10 * 250 + 1 and sampled.t[-1] == pytest.approx(20.0)
    q, dq, ddq = tr.evaluate(sampled.t)
    np.testing.assert_array_equal(sampled.q, q)
    # at rest in the start pose at both ends (the rest conditions of the parametrisation, to round-off)
    np.testing.assert_allclose(sampled.dq[[0, -1]], 0.0, atol=1e-12)
    np.testing.assert_allclose(sampled.q[-1], sampled.q[0], atol=1e-12)
    path = write_excitation_csv(sampled, tmp_path / "exc.csv")
    with path.open() as fh:
        header = next(csv.reader(fh))
    assert header[:2] == ["t", "position_shoulder_pan_joint"]
    assert header[-1] == "acceleration_wrist_3_joint" and len(header) == 1 + 3 * 6
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    # 10 significant digits in the file
    np.testing.assert_allclose(table[:, 1 + 6 : 1 + 12], dq, rtol=1e-9, atol=1e-12, err_msg="velocity columns")
    np.testing.assert_allclose(table[:, 1 + 12 :], ddq, rtol=1e-9, atol=1e-12, err_msg="acceleration columns")
    assert np.all(sampled.margins["position"] > 0) and np.all(sampled.margins["velocity"] > 0)


def test_a_sample_beyond_a_limit_is_refused_naming_joint_value_and_excess(six_dof: RobotModel,
                                                                         start: FourierTrajectory) -> None:  # fmt: skip
    # twice the velocity limit (the start stays within the torque and workspace bounds, so 4 x it may not leave
    # the joint ranges); only the joint limits are asked here (no floor, no self-collision, no torque bound)
    _, dq, _ = start.evaluate(np.arange(0.0, start.period, 0.01))
    k = 2.0 * float(np.max(six_dof.velocity_limit / np.abs(dq).max(axis=0).clip(1e-9)))
    fast = FourierTrajectory(start.base_frequency, k * start.a, k * start.b, start.offset)
    joints_only = excitation_limits(six_dof, torque_fraction=None, floor=None, self_collision=False)[0]
    beyond = r"joint \d \(\w+\) \w+ -?[\d.]+ rad(/s\^2)? at t = .* is beyond"
    with pytest.raises(ExcitationLimitError, match=beyond) as e:
        sample_excitation(fast, six_dof, rate=100.0, max_acceleration=2.0, limits=joints_only)
    assert e.value.excess > 0 and abs(e.value.value) > abs(e.value.limit)
    assert 0 <= e.value.joint < 6 and e.value.quantity in ("position", "velocity", "acceleration")


def test_a_pose_close_to_a_limit_warns(six_dof: RobotModel, start: FourierTrajectory) -> None:
    near = six_dof.upper_limit - 0.01  # 0.01 rad from the upper limit of +-3.1 rad joints
    still = FourierTrajectory(start.base_frequency, 1e-6 * start.a, 1e-6 * start.b, near)
    close = r"joint 1 \(shoulder_pan_joint\) position comes within 0\.0(1|099\d*) rad of its limit"
    joints_only = excitation_limits(six_dof, torque_fraction=None, floor=None, self_collision=False)[0]
    with pytest.warns(ExcitationMarginWarning, match=close):  # (at +3.09 rad the arm reaches below its base)
        sample_excitation(still, six_dof, rate=100.0, limits=joints_only)


def test_a_rate_too_low_for_the_highest_harmonic_is_refused(six_dof: RobotModel, start: FourierTrajectory) -> None:
    # 5 harmonics of 0.1 Hz: the highest at 0.5 Hz needs 20 samples per period, 10 Hz
    with pytest.raises(ConfigError, match=r"rate 5 Hz is too low .* highest harmonic at 0\.5 Hz: use at least 10 Hz"):
        sample_excitation(start, six_dof, rate=5.0)


def test_excite_writes_the_csv_with_units_named(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    path = write_six_dof_urdf(tmp_path / "robot")
    out = tmp_path / "exc"
    csv_path = out / "excitation.csv"
    code = main(["excite", "--robot", str(path), "--ee-frame", SIX_DOF_TOOL, "--maxiter", "0", "--harmonics", "3",
                 "--periods", "1", "--csv", str(csv_path), "--rate", "100", "--quiet", "--out", str(out)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "excitation sampled at 100 Hz (base frequency 0.1 Hz, 3 harmonics up to 0.3 Hz" in text
    assert "position [rad]" in text and "acceleration [rad/s^2]" in text
    assert np.loadtxt(out / "excitation.csv", delimiter=",", skiprows=1).shape == (10 * 100 + 1, 1 + 18)
    doc = json.loads((out / "excitation.json").read_text())
    assert doc["trajectory"]["base_frequency_hz"] == pytest.approx(0.1, rel=1e-15)
    assert "Hz" in doc["units"]["trajectory"]
