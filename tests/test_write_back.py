"""The identified model written into a copy of the user's URDF/MJCF: the copy loads (controller model and
plant), and its model is the identified one.

Tolerances: the file stores 12 significant digits per number, so link parameters are off by ~1e-12
relative; M(q), g(q) and C(q, dq) dq of the reloaded file match the identified model to 1e-9 (absolute,
for entries of order 0.01..100, the same bound as tests/test_model_agreement.py), while a wrong frame,
a COM not moved to the link frame or a lumped link counted twice shows up at 1e-3 or more.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_TOOL, write_six_dof_mjcf, write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.errors import ModelError
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, identify_dynamics
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.export._robot_xml import read_xml, relocate_paths
from reflexarm.ident.export.write_back import with_consistent_links, write_identified_robot
from reflexarm.robots.perturbation import perturb_model
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim import Plant, SensorNoise
from test_model_agreement import check_agreement

#: Agreement of the reloaded file with the identified model (see the module docstring).
ATOL = 1e-9


def _exact_log(robot: RobotModel, friction: FrictionParameters, seed: int = 0) -> RobotLog:
    rng = np.random.default_rng(seed)
    a, b = 0.15 * rng.normal(size=(2, robot.n, 5))
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(robot.n))
    t = np.arange(0.0, 20.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters()
    return RobotLog(t, q, dq, tau + friction.compute_torque(dq), ddq=ddq, source="exact")


def _identify(path: Path, friction: FrictionParameters | None = None):  # type: ignore[no-untyped-def]
    true = load_robot(path, ee_frame=SIX_DOF_TOOL)
    nominal = perturb_model(true, 0.3, seed=1)  # the user's file: inertias off by up to 30 %
    fr = FrictionParameters.from_model(true.friction) if friction is None else friction
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a negative friction below warns; tested in test_ident_any_arm
        res = identify_dynamics(nominal, _exact_log(true, fr), method="combined", noise_variance=None)
    return true, nominal, res


_CACHE: dict[str, tuple[RobotModel, RobotModel, object]] = {}


def _identified(tmp_path: Path, writer):  # type: ignore[no-untyped-def]
    """The identification of the 6-DoF arm written by ``writer`` (one per format per session: the
    consistency projection takes ~10 s); the user's file is rewritten into ``tmp_path`` each time."""
    key = writer.__name__
    if key not in _CACHE:
        _CACHE[key] = _identify(writer(tmp_path / "first"))
    true, nominal, res = _CACHE[key]
    return true, nominal, res


def _random_states(robot: RobotModel, k: int, seed: int = 0):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    for _ in range(k):
        yield rng.uniform(robot.lower_limit, robot.upper_limit), rng.normal(0.0, 1.5, robot.n)


@pytest.mark.parametrize("writer", [write_six_dof_urdf, write_six_dof_mjcf], ids=["urdf", "mjcf"])
def test_written_file_loads_and_its_model_is_the_identified_one(tmp_path: Path, writer) -> None:  # type: ignore[no-untyped-def]
    _, nominal, res = _identified(tmp_path, writer)
    out, notes = write_identified_robot(res, nominal, tmp_path / "out" / f"identified{nominal.source.suffix}")
    consistent, _ = with_consistent_links(res, nominal)
    identified = consistent.to_robot_model(nominal)
    back = load_robot(out, ee_frame=SIX_DOF_TOOL)
    assert back.joint_names == nominal.joint_names and notes
    for q, dq in _random_states(back, 50):
        np.testing.assert_allclose(
            back.compute_mass_matrix(q), identified.compute_mass_matrix(q), atol=ATOL, err_msg="M"
        )
        np.testing.assert_allclose(back.compute_gravity(q), identified.compute_gravity(q), atol=ATOL, err_msg="g")
        np.testing.assert_allclose(
            back.compute_nonlinear_effects(q, dq),
            identified.compute_nonlinear_effects(q, dq),
            atol=ATOL,
            err_msg="C dq",
        )
    # the regression's own prediction: Phi_b beta_b of the consistent result, with the file's friction
    q, dq = next(_random_states(back, 1, seed=3))
    ddq = np.linspace(-1.0, 1.0, back.n)
    np.testing.assert_allclose(
        back.compute_motor_torque(q, dq, ddq)
        - back.friction.compute_torque(dq)
        + consistent.friction.compute_torque(dq),
        consistent.compute_torque(nominal, q, dq, ddq)[0],
        atol=1e-8,  # Phi_b beta_b against rnea of the written links: 1e-9 per term over ~40 terms
    )
    # 12 significant digits in the file
    np.testing.assert_allclose(back.friction.coulomb, consistent.friction.coulomb, rtol=1e-11, err_msg="mu_C")
    np.testing.assert_allclose(back.friction.viscous, consistent.friction.viscous, rtol=1e-11, err_msg="d_v")


@pytest.mark.parametrize("writer", [write_six_dof_urdf, write_six_dof_mjcf], ids=["urdf", "mjcf"])
def test_the_plant_reads_the_written_file_as_the_controller_does(tmp_path: Path, writer) -> None:  # type: ignore[no-untyped-def]
    _, nominal, res = _identified(tmp_path, writer)
    out, _ = write_identified_robot(res, nominal, tmp_path / "out" / f"identified{nominal.source.suffix}")
    back = load_robot(out, ee_frame=SIX_DOF_TOOL)
    plant = Plant(back, noise=SensorNoise.none())
    worst = check_agreement(back, plant, n_states=20)
    assert max(worst.values()) < ATOL, worst


def test_negative_friction_is_written_as_zero_and_said_so(tmp_path: Path) -> None:
    true = load_robot(write_six_dof_urdf(tmp_path / "user"), ee_frame=SIX_DOF_TOOL)
    fr = FrictionParameters(true.friction.viscous, true.friction.coulomb * np.array([1, 1, -1, 1, 1, 1]))
    _, nominal, res = _identify(Path(true.source), friction=fr)  # type: ignore[arg-type]
    out, notes = write_identified_robot(res, nominal, tmp_path / "out" / "identified.urdf")
    back = load_robot(out, ee_frame=SIX_DOF_TOOL)
    assert back.friction.coulomb[2] == 0.0
    assert any("negative friction written as 0: joint 3 (elbow_joint) mu_C -0.9" in n for n in notes), notes


def test_the_copy_must_keep_the_source_format(tmp_path: Path) -> None:
    _, nominal, res = _identified(tmp_path, write_six_dof_urdf)
    with pytest.raises(ModelError, match=r"the copy of ur_like_6dof.urdf must be a .urdf file like its source"):
        write_identified_robot(res, nominal, tmp_path / "identified.xml")


URDF_WITH_MESHES = """<robot name="m">
  <link name="a"><visual><geometry><mesh filename="meshes/a.stl"/></geometry></visual>
    <collision><geometry><mesh filename="package://arm/meshes/a.stl"/></geometry></collision></link>
</robot>
"""
MJCF_WITH_ASSETS = """<mujoco model="m">
  <compiler meshdir="assets"/>
  <include file="parts/scene.xml"/>
  <asset><mesh name="a" file="a.stl"/><texture name="t" type="2d" file="tex/t.png"/></asset>
</mujoco>
"""


def test_relative_file_paths_still_resolve_from_the_copys_folder(tmp_path: Path) -> None:
    src = tmp_path / "robot"
    src.mkdir()
    (src / "arm.urdf").write_text(URDF_WITH_MESHES)
    (src / "arm.xml").write_text(MJCF_WITH_ASSETS)
    dst = tmp_path / "results" / "run1"
    dst.mkdir(parents=True)
    urdf = read_xml(src / "arm.urdf")
    assert relocate_paths(urdf, "urdf", src, dst) == 1
    meshes = [m.get("filename") for m in urdf.iter("mesh")]
    assert meshes == ["../../robot/meshes/a.stl", "package://arm/meshes/a.stl"]  # package:// left to ROS
    root = read_xml(src / "arm.xml")
    assert relocate_paths(root, "mjcf", src, dst) == 3
    assert root.find("compiler").get("meshdir") == "../../robot/assets"  # type: ignore[union-attr]
    assert root.find("include").get("file") == "../../robot/parts/scene.xml"  # type: ignore[union-attr]
    assert root.find("asset/mesh").get("file") == "a.stl"  # type: ignore[union-attr]  # through meshdir
    assert root.find("asset/texture").get("file") == "../../robot/tex/t.png"  # type: ignore[union-attr]


def test_an_arm_cut_from_its_file_keeps_the_locked_gripper_and_reloads_with_the_same_cut(tmp_path: Path) -> None:
    from reflexarm.robots.example_arms import write_ur_like_arm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file's notes (ros2_control, gazebo, meshes)
        true = load_robot(write_ur_like_arm(tmp_path / "user"), tip="tool0")
    assert true.cut is not None and set(true.cut.locked) == {"gripper_left_finger_joint", "gripper_right_finger_joint"}
    rng = np.random.default_rng(5)
    a, b = 0.15 * rng.normal(size=(2, true.n, 5))
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(true.n))
    t = np.arange(0.0, 20.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    tau = BatchRegressor(true).compute_regressor(q, dq, ddq) @ true.inertial_parameters()
    res = identify_dynamics(true, RobotLog(t, q, dq, tau, ddq=ddq), method="combined", noise_variance=None)
    out, notes = write_identified_robot(res, true, tmp_path / "out" / "identified.urdf")
    assert any("links behind locked joints (gripper_left_finger, gripper_right_finger) keep" in n for n in notes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back = load_robot(out, **true.load_arguments())
        plant = Plant(back, noise=SensorNoise.none())  # MuJoCo needs mass on the locked fingers' bodies
    identified = with_consistent_links(res, true)[0].to_robot_model(true)
    for qq, _ in _random_states(back, 20, seed=6):
        np.testing.assert_allclose(back.compute_mass_matrix(qq), identified.compute_mass_matrix(qq), atol=ATOL)
        np.testing.assert_allclose(back.compute_gravity(qq), identified.compute_gravity(qq), atol=ATOL)
    worst = check_agreement(back, plant, n_states=10)
    assert max(worst.values()) < ATOL, worst
    # an estimate whose last link, without the locked fingers, has no physical inertia (two base
    # parameters of wrist_3 moved by 0.02 kg m^2, far beyond its own 0.01): projected with the fingers
    # held at the file's inertias, and the copy is still the projected model
    beta = res.beta_b.copy()
    moved = [i for i, name in enumerate(res.base.base_names()) if name in ("Iyz_wrist_3_joint", "Ixy_wrist_3_joint")]
    assert len(moved) == 2
    beta[moved] += 0.02
    off = replace(res, beta_b=beta)
    projected, how = with_consistent_links(off, true)
    assert how.startswith("the nearest physically consistent link parameters")
    out, _ = write_identified_robot(off, true, tmp_path / "out" / "projected.urdf")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back = load_robot(out, **true.load_arguments())
    identified = projected.to_robot_model(true)
    for qq, _ in _random_states(back, 20, seed=7):
        np.testing.assert_allclose(back.compute_mass_matrix(qq), identified.compute_mass_matrix(qq), atol=ATOL)


def test_an_mjcf_with_a_fixed_body_lumped_into_its_link_compiles_and_matches(tmp_path: Path) -> None:
    # the built-in Panda's `tool` body (0.25 kg) is fixed to link 7: the copy lumps it into link 7 and leaves
    # `tool` massless; MuJoCo refuses an all-zero fullinertia, so the copy must still compile (found end to end)
    true = load_robot("panda")
    nominal = perturb_model(true, 0.3, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify_dynamics(
            nominal,
            _exact_log(true, FrictionParameters.from_model(true.friction)),
            method="combined",
            noise_variance=None,
        )
        out, _ = write_identified_robot(res, nominal, tmp_path / "panda_identified.xml")
        back = load_robot(out, ee_frame="ee")
        Plant(back)  # MuJoCo compiles the copy
    consistent, _ = with_consistent_links(res, nominal)
    identified = consistent.to_robot_model(nominal)
    for q, _dq in _random_states(back, 20):
        np.testing.assert_allclose(back.compute_mass_matrix(q), identified.compute_mass_matrix(q), atol=ATOL)
        np.testing.assert_allclose(back.compute_gravity(q), identified.compute_gravity(q), atol=ATOL)
