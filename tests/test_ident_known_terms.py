"""Known joint terms (armature, joint springs): subtracted before the regression, recovered exactly."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from reflexarm.errors import IdentificationError
from reflexarm.ident import (
    BatchRegressor,
    DynamicsIdentification,
    FrictionParameters,
    RobotLog,
    compute_base_parameters,
    identify_dynamics,
)
from reflexarm.ident.estimation import identify as estimation
from reflexarm.ident.estimation.base_parameters import random_samples
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.robots import load_robot

# A four-joint spatial arm with the Menagerie Panda's kind of rotor armature (0.1 kg m^2 on the first
# joint) and springs with rest positions on two joints; no damping or frictionloss, so MuJoCo's inverse
# dynamics is the rigid body plus exactly these two terms.
KNOWN_TERMS_ARM = """<mujoco model="armature_spring_arm">
  <compiler angle="radian"/>
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="link1" pos="0 0 0.3">
      <joint name="j1" axis="0 0 1" range="-2.5 2.5" armature="{a1}"/>
      <inertial pos="0.01 0.02 0.1" mass="3" diaginertia="0.03 0.025 0.01"/>
      <body name="link2" pos="0 0 0.2">
        <joint name="j2" axis="0 1 0" range="-1.8 1.8" armature="{a2}" stiffness="{k2}" springref="0.4"/>
        <inertial pos="0.15 0 0.01" mass="2" diaginertia="0.01 0.02 0.02"/>
        <body name="link3" pos="0.3 0 0">
          <joint name="j3" axis="0 1 0" range="-2 2" armature="{a3}"/>
          <inertial pos="0.1 0.01 0" mass="1.2" diaginertia="0.004 0.008 0.007"/>
          <body name="link4" pos="0.25 0 0">
            <joint name="j4" axis="1 0 0" range="-2.8 2.8" armature="{a4}" stiffness="{k4}" springref="-0.3"/>
            <inertial pos="0.05 0.02 0.01" mass="0.6" diaginertia="0.001 0.0015 0.0012"/>
            <site name="ee" pos="0.1 0 0"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
ARMATURE = (0.1, 0.08, 0.05, 0.02)  # [kg m^2]
STIFFNESS = {"k2": 25.0, "k4": 4.0}  # [Nm/rad]
N_SAMPLES = 400

# Pinocchio (our regressor) and MuJoCo (the torques) evaluate the same dynamics in double precision;
# they agree to ~1e-12 Nm on torques of O(10) Nm (test_robot_files.py uses 1e-9 as the bound).
TORQUE_ATOL = 1e-9
# Noise-free and well excited (random samples over the joint range; condition number of the
# column-normalised regressor 2.8), the base parameters come back to round-off: measured 4e-15 of the
# largest parameter; 1e-10 leaves room for other BLAS and still fails at any modelling error.
RECOVERY_RTOL = 1e-10
# Without the correction the armature alone (0.02..0.1 kg m^2, as large as the links' inertias) and the
# springs (up to 25 Nm/rad) are misattributed: the error is of the order of the parameters themselves.
# (measured: 3.8 times the largest parameter). 1 % is far above round-off and far below that.
MISFIT_MIN = 1e-2


def _write_arm(tmp_path: Path, *, armature: tuple[float, ...], stiffness: dict[str, float], name: str) -> Path:
    text = KNOWN_TERMS_ARM.format(a1=armature[0], a2=armature[1], a3=armature[2], a4=armature[3], **stiffness)
    path = tmp_path / name
    path.write_text(text)
    return path


def _mujoco_torques(path: Path, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """Inverse dynamics of MuJoCo itself (independent of Pinocchio and of reflexarm)."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    tau = np.empty_like(q)
    for k in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], dq[k], ddq[k]
        mujoco.mj_inverse(model, data)
        tau[k] = data.qfrc_inverse
    return tau


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("known_terms")
    path = _write_arm(tmp, armature=ARMATURE, stiffness=STIFFNESS, name="arm.xml")
    bare = _write_arm(tmp, armature=(0.0,) * 4, stiffness={"k2": 0.0, "k4": 0.0}, name="bare.xml")
    robot = load_robot(path, ee_frame="ee")
    q, dq, ddq = random_samples(robot, N_SAMPLES, np.random.default_rng(7))
    tau = _mujoco_torques(path, q, dq, ddq)
    t = 1e-3 * np.arange(N_SAMPLES)
    log = RobotLog.from_arrays(t, q, dq, tau, ddq=ddq, source="armature_spring_arm")
    return robot, load_robot(bare, ee_frame="ee"), log


def _identify(robot, log) -> DynamicsIdentification:
    zero = FrictionParameters(np.zeros(robot.n), np.zeros(robot.n))
    return identify_dynamics(robot, log, method="sequential", friction=zero, noise_variance=None)


def test_the_file_has_armature_and_springs_and_rnea_is_regressor_plus_known_terms(arm):
    robot, _, log = arm
    known = KnownJointTerms.from_robot(robot)
    np.testing.assert_allclose(known.armature, ARMATURE, rtol=1e-12)
    assert robot.has_springs and not known.is_zero
    Y = BatchRegressor(robot).compute_regressor(log.q, log.dq, log.ddq)
    rigid = Y @ robot.inertial_parameters()
    np.testing.assert_allclose(rigid + known.compute_torque(log.q, log.ddq), log.tau, atol=TORQUE_ATOL)
    pin_rnea = np.array([robot.compute_inverse_dynamics(log.q[k], log.dq[k], log.ddq[k]) for k in range(20)])
    np.testing.assert_allclose(pin_rnea, log.tau[:20], atol=TORQUE_ATOL)
    # the known terms matter here: the rigid body alone misses them by Newton-metres
    assert np.abs(rigid - log.tau).max() > 1.0


def test_base_parameters_are_recovered_with_armature_and_springs_subtracted(arm):
    robot, _, log = arm
    result = _identify(robot, log)
    truth = compute_base_parameters(robot).base_from_standard(robot.inertial_parameters())
    scale = np.abs(truth).max()
    np.testing.assert_allclose(result.beta_b, truth, rtol=0, atol=RECOVERY_RTOL * scale)
    assert result.known_terms is not None and result.known_terms.matches(KnownJointTerms.from_robot(robot))
    assert any("armature" in note and "joint springs" in note for note in result.notes), result.notes
    # the prediction adds the known terms back: it reproduces the measured torques
    predicted = result.compute_torque(robot, log.q, log.dq, log.ddq)
    np.testing.assert_allclose(predicted, log.tau, atol=1e3 * TORQUE_ATOL)


def test_without_the_correction_the_recovery_is_wrong(arm):
    """The same torques identified as if the file had neither term: the base parameters are off."""
    robot, bare, log = arm
    truth = compute_base_parameters(robot).base_from_standard(robot.inertial_parameters())
    result = _identify(bare, log)
    assert result.known_terms is not None and result.known_terms.is_zero
    error = np.abs(result.beta_b - truth).max() / np.abs(truth).max()
    assert error > MISFIT_MIN, f"relative error {error:.3g}"


def test_known_terms_survive_the_dict_and_guard_the_model(arm):
    robot, bare, log = arm
    result = _identify(robot, log)
    again = DynamicsIdentification.from_dict(result.to_dict())
    assert again.known_terms is not None and again.known_terms.matches(result.known_terms)
    model = result.to_robot_model(robot)
    # the returned model's own dynamics (rigid body + the file's armature and springs) give the torques
    k = np.arange(0, N_SAMPLES, 40)
    got = np.array([model.compute_inverse_dynamics(log.q[i], log.dq[i], log.ddq[i]) for i in k])
    np.testing.assert_allclose(got, log.tau[k], atol=1e-6 * np.abs(log.tau).max())
    with pytest.raises(IdentificationError, match="other armature/joint springs"):
        result.to_robot_model(bare)


MENAGERIE_PANDA = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "menagerie" / "panda_nohand.xml"
# The Menagerie Panda without the correction: measured 1.5e-2 of the largest base parameter (armature
# 0.1 kg m^2 per joint is partly absorbed by the links' inertias); 1e-3 is far above round-off.
PANDA_MISFIT_MIN = 1e-3


@pytest.mark.skipif(not MENAGERIE_PANDA.is_file(), reason=f"Menagerie Panda not available at {MENAGERIE_PANDA}")
def test_menagerie_panda_with_its_armature_is_recovered_from_pinocchio_rnea(monkeypatch):
    robot = load_robot(MENAGERIE_PANDA, ee_frame="attachment_site")
    np.testing.assert_allclose(KnownJointTerms.from_robot(robot).armature, 0.1, rtol=1e-12)
    q, dq, ddq = random_samples(robot, N_SAMPLES, np.random.default_rng(1))
    # Pinocchio's rnea includes armature * ddq (the torque the motors supply for the rotors too)
    tau = np.array([robot.compute_inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(N_SAMPLES)])
    log = RobotLog.from_arrays(1e-3 * np.arange(N_SAMPLES), q, dq, tau, ddq=ddq, source="menagerie panda")
    truth = compute_base_parameters(robot).base_from_standard(robot.inertial_parameters())
    scale = np.abs(truth).max()
    np.testing.assert_allclose(_identify(robot, log).beta_b, truth, rtol=0, atol=RECOVERY_RTOL * scale)
    # the same identification with the known terms ignored (as before they were subtracted) is off
    n = robot.n
    nothing = KnownJointTerms(np.zeros(n), np.zeros(n), np.zeros(n))
    monkeypatch.setattr(estimation.KnownJointTerms, "from_robot", classmethod(lambda cls, robot: nothing))
    error = np.abs(_identify(robot, log).beta_b - truth).max() / scale
    assert error > PANDA_MISFIT_MIN, f"relative error {error:.3g}"
