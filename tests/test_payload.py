"""The payload at the tool (issue 17, item 4): mass and COM identified from a log with the arm's model known,
and a change of load found in a log, with its time.

The logs are simulated on the MuJoCo plant of the UR-like 6-DoF arm (``ident_arms``) with a payload link
fixed to the tool frame in the plant's file and not in the model: the truth (mass, offset) is the generator's.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_TOOL, six_dof_urdf
from reflexarm import load_robot
from reflexarm.errors import IdentificationError
from reflexarm.experiments.identification import simulate_log
from reflexarm.ident import RobotLog, preprocess_log
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.payload import detect_payload_change, identify_payload, with_payload
from reflexarm.robots.robot_model import RobotModel

PAYLOAD_MASS = 1.5  # [kg]
PAYLOAD_OFFSET = np.array([0.05, 0.0, 0.0])  # COM in the tool frame [m]
#: Mass within 2 % (30 g): measured 1.501 kg (point mass) and 1.503 kg (10 parameters); the mass is seen
#: through the gravity torque of joints 2-4 (tens of Nm per kg) against 0.07 Nm torque noise.
MASS_RTOL = 0.02
#: COM within 10 mm per axis: measured errors up to 2.4 mm (point mass) and 12 mm (10 parameters, whose
#: inertia columns take part of the first moment along the tool axis; hence its looser check below); the
#: change's COM (fitted on either side of the change) up to 7.6 mm at 100 Hz.
COM_ATOL = 0.010
#: The change is located within this of the true time [s]: measured within 32 ms at 1 kHz and 100 Hz, picked
#: up or put down (the 10 Hz filter smears the step of the concatenated logs over ~0.1 s; the split is chosen
#: on a grid of ~10 ms).
CHANGE_TIME_ATOL = 0.1


def payload_urdf(mass: float, offset: np.ndarray) -> str:
    link = (
        f'  <link name="payload"><inertial><origin xyz="0 0 0"/><mass value="{mass:g}"/>'
        '<inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>\n'
        f'  <joint name="payload_fixed" type="fixed"><parent link="{SIX_DOF_TOOL}"/><child link="payload"/>'
        f'<origin xyz="{offset[0]:g} {offset[1]:g} {offset[2]:g}"/></joint>\n'
    )
    return six_dof_urdf().replace("</robot>", link + "</robot>")


def motion(n: int) -> FourierTrajectory:
    """10 s of random Fourier motion, each joint peaking at 1 rad/s."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(n, 5)), rng.normal(size=(n, 5))
    tr = FourierTrajectory.from_hz(0.1, a, b, np.zeros(n))
    _, dq, _ = tr.evaluate(np.arange(0.0, tr.period, 1e-2))
    s = 1.0 / np.abs(dq).max(axis=0)
    return FourierTrajectory.from_hz(0.1, a * s[:, None], b * s[:, None], np.zeros(n))


@pytest.fixture(scope="module")
def arms(tmp_path_factory: pytest.TempPathFactory) -> tuple[RobotModel, RobotModel]:
    folder = tmp_path_factory.mktemp("arm")
    (folder / "arm.urdf").write_text(six_dof_urdf())
    (folder / "arm_payload.urdf").write_text(payload_urdf(PAYLOAD_MASS, PAYLOAD_OFFSET))
    arm = load_robot(folder / "arm.urdf", ee_frame=SIX_DOF_TOOL)
    with pytest.warns(Warning, match="without collision geometry"):
        loaded = load_robot(folder / "arm_payload.urdf", ee_frame=SIX_DOF_TOOL)
    return arm, loaded


@pytest.fixture(scope="module")
def raw_logs(arms: tuple[RobotModel, RobotModel]) -> tuple[RobotLog, RobotLog]:
    arm, loaded = arms
    tr = motion(arm.n)
    free, _ = simulate_log(arm, tr, tr.duration, seed=3)
    carrying, _ = simulate_log(loaded, tr, tr.duration, controller_model=arm, seed=2)  # the model lacks the load
    return free, carrying


@pytest.mark.parametrize("inertia", [False, True])
def test_a_known_payload_is_recovered(arms, raw_logs, inertia: bool) -> None:
    arm, _ = arms
    p = identify_payload(arm, preprocess_log(raw_logs[1]), inertia=inertia)
    assert p.frame == SIX_DOF_TOOL
    np.testing.assert_allclose(p.mass, PAYLOAD_MASS, rtol=MASS_RTOL, err_msg="mass")
    np.testing.assert_allclose(p.com, PAYLOAD_OFFSET, atol=COM_ATOL if not inertia else 1.5 * COM_ATOL, err_msg="COM")
    assert np.all(p.residual_rms_after < p.residual_rms_before + 1e-9)
    # the model with the payload added predicts the torque as well as the fit (updating a model file)
    again = identify_payload(arm, preprocess_log(raw_logs[1]), model=with_payload(arm, p), inertia=inertia)
    assert abs(again.mass) < MASS_RTOL * PAYLOAD_MASS


def test_no_payload_gives_a_mass_near_zero(arms, raw_logs) -> None:
    arm, _ = arms
    p = identify_payload(arm, preprocess_log(raw_logs[0]))
    assert abs(p.mass) < MASS_RTOL * PAYLOAD_MASS, p.describe()


@pytest.mark.parametrize("step", [1, 10], ids=["1kHz", "100Hz"])
@pytest.mark.parametrize("picked_up", [True, False], ids=["picked_up", "put_down"])
def test_a_payload_picked_up_or_put_down_halfway_is_flagged_with_its_time_and_mass(
    arms, raw_logs, picked_up: bool, step: int
) -> None:
    arm, _ = arms
    first, second = raw_logs if picked_up else raw_logs[::-1]
    t_change = first.t[-1] + 1e-3  # the second run continues the clock: the load changes here
    both = RobotLog(
        np.r_[first.t, second.t + t_change], np.r_[first.q, second.q], np.r_[first.dq, second.dq],
        np.r_[first.tau, second.tau], source="changed",
    ).select(slice(None, None, step))  # fmt: skip
    change = detect_payload_change(arm, preprocess_log(both))
    assert change.changed, change.reason
    assert abs(change.time - t_change) < CHANGE_TIME_ATOL, change.reason
    sign = 1.0 if picked_up else -1.0
    np.testing.assert_allclose(change.mass_change, sign * PAYLOAD_MASS, rtol=MASS_RTOL, err_msg=change.reason)
    np.testing.assert_allclose(change.com_change, PAYLOAD_OFFSET, atol=COM_ATOL, err_msg=change.reason)
    assert change.reason.startswith(f"the load changed at t = {change.time:.3f} s: a mass of {sign * 1.5:+.1f}")


@pytest.mark.parametrize("which", [0, 1])
def test_a_constant_load_is_not_flagged(arms, raw_logs, which: int) -> None:
    arm, _ = arms
    change = detect_payload_change(arm, preprocess_log(raw_logs[which]))
    assert not change.changed, change.reason
    assert change.reason.startswith("no change of load")


def test_a_log_too_short_for_two_segments_is_refused(arms, raw_logs) -> None:
    arm, _ = arms
    short = preprocess_log(raw_logs[0]).select(slice(0, 3000))
    with pytest.raises(IdentificationError, match=r"is too short to look for a change of load \(two segments"):
        detect_payload_change(arm, short)


def test_a_tool_frame_not_on_the_last_link_is_refused(tmp_path: Path) -> None:
    (tmp_path / "arm.urdf").write_text(six_dof_urdf())
    arm = load_robot(tmp_path / "arm.urdf", ee_frame="elbow_link")
    t = np.arange(0.0, 1.0, 1e-3)
    z = np.zeros((t.size, 6))
    with pytest.raises(IdentificationError, match=r"tool frame 'elbow_link' is not on the last link"):
        identify_payload(arm, RobotLog(t, z, z, z, ddq=z))


def test_identify_payload_command_writes_the_payload_and_the_change_check(
    arms, raw_logs, tmp_path: Path, capsys
) -> None:
    from reflexarm.cli import main
    from reflexarm.ident import save_log

    arm, _ = arms
    log = save_log(raw_logs[1], tmp_path / "carrying.npz")
    out = tmp_path / "payload"
    assert main(["identify", "payload", str(log), "--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL, "--quiet",
                 "--out", str(out)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "payload (point mass) at 'tool': mass 1.5" in text
    assert "no change of load" in text
    doc = json.loads((out / "payload.json").read_text())
    np.testing.assert_allclose(doc["payload"]["mass"], PAYLOAD_MASS, rtol=MASS_RTOL)
    assert doc["change"]["changed"] is False
    # --write-model needs the model file it updates
    assert main(["identify", "payload", str(log), "--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL, "--quiet",
                 "--write-model", str(tmp_path / "m.json"), "--out", str(out)]) != 0  # fmt: skip
    assert "--write-model needs --model" in capsys.readouterr().err


def test_a_model_file_updated_with_the_payload_explains_the_load(arms, raw_logs, tmp_path: Path) -> None:
    from reflexarm.ident import (
        identify_dynamics,
        load_identified_model,
        project_physically_consistent,
        save_identified_model,
    )
    from reflexarm.ident.payload import write_model_with_payload

    arm, _ = arms
    free, carrying = (preprocess_log(lg) for lg in raw_logs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # conditioning of a 10 s log: not what is tested here
        fit = project_physically_consistent(identify_dynamics(arm, free, method="combined", min_speed=0.055), arm)
    path = save_identified_model(fit, arm, tmp_path / "model.json")
    model = load_identified_model(path, arm)
    p = identify_payload(arm, carrying, model=model)
    np.testing.assert_allclose(p.mass, PAYLOAD_MASS, rtol=MASS_RTOL)  # against an identified model too
    updated = load_identified_model(write_model_with_payload(path, p, tmp_path / "with_payload.json"), arm)
    np.testing.assert_allclose(updated.inertial_parameters()[-10:] - model.inertial_parameters()[-10:], p.parameters,
                               atol=1e-9)  # fmt: skip
    assert abs(identify_payload(arm, carrying, model=updated).mass) < MASS_RTOL * PAYLOAD_MASS


def test_identify_payload_command_on_a_log_where_the_load_changed_reports_the_load_after_it(
    arms, raw_logs, tmp_path: Path, capsys
) -> None:
    from reflexarm.cli import main
    from reflexarm.ident import save_log

    arm, _ = arms
    free, carrying = raw_logs
    t_change = free.t[-1] + 1e-3
    both = RobotLog(
        np.r_[free.t, carrying.t + t_change], np.r_[free.q, carrying.q], np.r_[free.dq, carrying.dq],
        np.r_[free.tau, carrying.tau], source="picked_up",
    )  # fmt: skip
    log = save_log(both, tmp_path / "picked_up.npz")
    out = tmp_path / "payload"
    assert main(["identify", "payload", str(log), "--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL, "--quiet",
                 "--out", str(out)]) == 0  # fmt: skip
    assert "the payload above averages the loads before and after the change; after it:" in capsys.readouterr().out
    doc = json.loads((out / "payload.json").read_text())
    assert doc["change"]["changed"] is True and doc["change"]["payload_is_after_the_change"] is True
    assert abs(doc["change"]["time"] - t_change) < CHANGE_TIME_ATOL
    np.testing.assert_allclose(doc["payload"]["mass"], PAYLOAD_MASS, rtol=MASS_RTOL)
