"""Cutting a serial arm out of a robot tree: base/tip links, locked joints, the plant frozen the same way.

References: the cut (reduced) Pinocchio model against (a) the whole file's Pinocchio model at the locked
configuration (rows/columns of the chain) and (b) the MuJoCo plant built from the same file with the
same joints frozen; the Atlas arm cut from the drcsim URDFs against the built-in ``atlas_v5_left_arm``.
The written UR5-like arm itself is tested in test_ur_like_arm.py.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from reflexarm.errors import ModelError
from reflexarm.robots import RobotFileWarning, RobotModel, load_robot
from reflexarm.robots.example_arms import UR_LIKE_FINGERS, UR_LIKE_TIP, write_ur_like_arm
from reflexarm.sim import Plant, SensorNoise
from test_model_agreement import ATOL, check_agreement

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "reference"
ATLAS_V5 = SHARED / "atlas" / "atlas_v5.urdf"  # Dec-2014 BDI mass properties (table C of left_arm_parameters.md)
ATLAS_FINAL = SHARED / "atlas" / "drcsim_456dd5d0" / "atlas_v5_simple_shapes.urdf"  # final masses (table A)
MENAGERIE = SHARED / "menagerie"
needs_shared = pytest.mark.skipif(not ATLAS_V5.is_file(), reason=f"reference files not available at {SHARED}")

#: Two double-precision evaluations of the same rigid-body expressions (reduced vs full Pinocchio model,
#: Pinocchio vs MuJoCo) differ by round-off, ~1e-13 for Atlas-size torques (tens of Nm); a misplaced
#: locked body or a lost mass shows up at 1e-3 or more.
EXACT = 1e-10

#: The built-in arm carries a 0.25 kg tool (body ``l_tool``, 0.06 m beyond ``l_hand``) that the drcsim
#: files do not have; its spatial inertia in the ``l_hand`` frame, as written in atlas_v5_left_arm.xml.
BUILTIN_TOOL = pin.Inertia(0.25, np.array([0.0, 0.09, 0.0]), np.diag([2e-4, 2e-4, 2e-4]))


def _quiet_load(path: Path | str, **kwargs: object) -> RobotModel:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        return load_robot(path, **kwargs)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def ur_arm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_ur_like_arm(tmp_path_factory.mktemp("arms"))


def _random_q(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    lo = np.maximum(robot.lower_limit, -np.pi)
    hi = np.minimum(robot.upper_limit, np.pi)
    return rng.uniform(lo, hi)


# ---------------------------------------------------------------------- reduced model == whole model
CUTS = [
    ("ur", {"tip": UR_LIKE_TIP}),
    ("ur", {"tip": UR_LIKE_TIP, "locked": {UR_LIKE_FINGERS[0]: 0.03}}),  # one finger open: asymmetric load
    ("ur", {"base": "upper_arm_link", "tip": "wrist_3_link"}),  # a sub-chain: the shoulder pan joint locked
    ("atlas", {"base": "utorso", "tip": "l_hand"}),
    ("atlas", {"base": "utorso", "tip": "l_hand", "locked": {"back_bky": 0.3, "back_bkx": -0.2, "r_arm_shx": 1.0}}),
    ("atlas", {"base": "pelvis", "tip": "l_hand", "locked": {"l_leg_kny": 1.2}}),  # the back joints on the arm
]


def _file(kind: str, ur_arm: Path) -> Path:
    if kind == "atlas" and not ATLAS_V5.is_file():
        pytest.skip(f"reference files not available at {SHARED}")
    return ur_arm if kind == "ur" else ATLAS_V5


@pytest.mark.parametrize(("kind", "cut"), CUTS)
def test_cut_model_is_the_whole_model_at_the_locks(ur_arm: Path, kind: str, cut: dict) -> None:
    """M(q) and g(q) of the cut model are the chain's rows and columns of the whole file's model with the
    other joints at their locked positions: every carried body kept its mass at the right place."""
    path = _file(kind, ur_arm)
    robot = _quiet_load(path, **cut)
    whole = pin.buildModelFromUrdf(str(path)) if kind == "ur" else _whole_atlas()
    data = whole.createData()
    chain = [whole.idx_vs[whole.getJointId(name)] for name in robot.joint_names]
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = _random_q(robot, rng)
        q_full = pin.neutral(whole)
        for name, value in robot.cut.locked.items():  # type: ignore[union-attr]
            q_full[whole.idx_qs[whole.getJointId(name)]] = value
        q_full[chain] = q
        M_full = pin.crba(whole, data, q_full)
        M_full = np.triu(M_full) + np.triu(M_full, 1).T
        g_full = pin.computeGeneralizedGravity(whole, data, q_full)
        np.testing.assert_allclose(robot.compute_mass_matrix(q), M_full[np.ix_(chain, chain)], rtol=0, atol=EXACT)
        np.testing.assert_allclose(robot.compute_gravity(q), g_full[chain], rtol=0, atol=EXACT)


def _whole_atlas() -> pin.Model:
    text = ATLAS_V5.read_text()  # drop the joint to the undefined 'head' link, as the loader does
    start = text.index('<joint name="neck_ry"')
    return pin.buildModelFromXML(text[:start] + text[text.index("</joint>", start) + len("</joint>") :])


@pytest.mark.parametrize(("kind", "cut"), CUTS)
def test_plant_freezes_the_same_joints(ur_arm: Path, kind: str, cut: dict) -> None:
    """The MuJoCo plant (locked joints deleted, bodies moved) and the cut Pinocchio model are one robot:
    M, g, C dq and the sensor Jacobian agree at 30 random states (tolerance of test_model_agreement)."""
    robot = _quiet_load(_file(kind, ur_arm), **cut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        plant = Plant(robot, noise=SensorNoise.none())
    assert plant.model.njnt == robot.n
    worst = check_agreement(robot, plant, n_states=30)
    assert max(worst.values()) <= ATOL, worst


# ---------------------------------------------------------------------- Atlas from the whole-robot files
@needs_shared
def test_atlas_cut_from_the_final_file_is_the_builtin_arm() -> None:
    """Cut from the file with the final masses (table A), the arm is the built-in one up to the built-in's
    0.25 kg tool beyond l_hand: adding that tool's inertia to the last link, M(q) and g(q) agree to round-off.
    The torso is upright in both (the back joints locked at 0)."""
    builtin = load_robot("atlas_v5_left_arm")
    cut = _quiet_load(ATLAS_FINAL, base="utorso", tip="l_hand")
    assert cut.joint_names == builtin.joint_names
    model = cut.pin_model.copy()
    model.inertias[model.njoints - 1] = model.inertias[model.njoints - 1] + BUILTIN_TOOL
    with_tool = RobotModel(model, ee_frame="l_hand")
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = _random_q(builtin, rng)
        np.testing.assert_allclose(with_tool.compute_mass_matrix(q), builtin.compute_mass_matrix(q), atol=EXACT)
        np.testing.assert_allclose(with_tool.compute_gravity(q), builtin.compute_gravity(q), atol=EXACT)
    np.testing.assert_array_equal(cut.effort_limit, builtin.effort_limit)
    np.testing.assert_array_equal(cut.lower_limit, builtin.lower_limit)


@needs_shared
def test_atlas_cut_from_atlas_v5_differs_only_by_its_older_masses() -> None:
    """atlas_v5.urdf carries the Dec-2014 mass properties (arm 17.66 kg vs 19.71 kg final, plus the built-in's
    tool): M and g differ (measured max 0.36 kg m^2 and 3.6 Nm over 100 states); with the built-in's inertial
    parameters the cut model's M and g are the built-in's to round-off, so kinematics and locks are the same."""
    builtin = load_robot("atlas_v5_left_arm")
    with pytest.warns(RobotFileWarning, match="joint 'neck_ry' leads to link 'head', which the file does not define"):
        cut = load_robot(ATLAS_V5, base="utorso", tip="l_hand")
    np.testing.assert_allclose(cut.inertial_parameters()[0::10].sum(), 17.659, rtol=1e-12)
    same = cut.with_inertial_parameters(builtin.inertial_parameters())
    rng = np.random.default_rng(1)
    differs = 0.0
    for _ in range(50):
        q = _random_q(builtin, rng)
        np.testing.assert_allclose(same.compute_mass_matrix(q), builtin.compute_mass_matrix(q), atol=EXACT)
        np.testing.assert_allclose(same.compute_gravity(q), builtin.compute_gravity(q), atol=EXACT)
        differs = max(differs, float(np.abs(cut.compute_gravity(q) - builtin.compute_gravity(q)).max()))
    assert differs > 1.0  # the masses really differ: the comparison above is not vacuous


@needs_shared
def test_tilted_torso_changes_gravity_torques() -> None:
    upright = _quiet_load(ATLAS_V5, base="utorso", tip="l_hand")
    bent = _quiet_load(ATLAS_V5, base="utorso", tip="l_hand", locked={"back_bky": 0.4})
    q = np.array([-0.3, -1.1, 1.6, 1.2, 0.0, 0.2, 0.0])
    assert np.abs(upright.compute_gravity(q) - bent.compute_gravity(q)).max() > 1.0
    np.testing.assert_allclose(upright.compute_mass_matrix(q), bent.compute_mass_matrix(q), atol=EXACT)


FLOATING_URDF = """<robot name="floating">
  <link name="world"/>
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>
    </inertial></link>
  <link name="arm"><inertial><origin xyz="0 0.02 0.1"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="float" type="floating"><parent link="world"/><child link="base"/><origin xyz="0 0 1" rpy="0.3 0 0"/>
  </joint>
  <joint name="ja" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0.1 0"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


def test_floating_urdf_base_is_fixed_at_the_files_pose(tmp_path: Path) -> None:
    """A URDF floating joint from a 'world' link: fixed where its origin puts the base (1 m up, rolled 0.3
    rad, so gravity acts on the hinge), with a note; the plant agrees."""
    path = tmp_path / "floating.urdf"
    path.write_text(FLOATING_URDF)
    with pytest.warns(RobotFileWarning, match="the floating base joint 'float' is fixed at the file's pose"):
        robot = load_robot(path, ee_frame="arm")
    assert robot.joint_names == ["ja"] and robot.cut is not None and robot.cut.base == "base"
    np.testing.assert_allclose(robot.compute_frame_pose([0.0], "base")[1], [0.0, 0.0, 1.0], atol=EXACT)
    # gravity in the rolled base frame is 9.81 (0, -sin 0.3, -cos 0.3); the COM sits at y=0.02, z=0.1 from the
    # hinge (x axis): g = -9.81 (0.1 sin 0.3 - 0.02 cos 0.3) = -0.1025 Nm (it would be +0.196 Nm unrolled)
    expected = -9.81 * (0.1 * np.sin(0.3) - 0.02 * np.cos(0.3))
    np.testing.assert_allclose(robot.compute_gravity([0.0]), [expected], rtol=0, atol=EXACT)
    plant = Plant(robot, noise=SensorNoise.none())
    assert max(check_agreement(robot, plant, n_states=10).values()) <= ATOL


@needs_shared
def test_humanoid_base_is_said_to_be_fixed() -> None:
    with pytest.warns(
        RobotFileWarning,
        match=r"base link 'utorso' is held fixed in the world \(the world frame is the "
        r"root link 'pelvis''s\); the joint\(s\) between them \['back_bkz', 'back_bky', 'back_bkx'\]",
    ):
        load_robot(ATLAS_V5, base="utorso", tip="l_hand")


# ---------------------------------------------------------------------- locks and their errors
@needs_shared
def test_locks_are_clipped_to_the_limits_with_a_note() -> None:
    with pytest.warns(RobotFileWarning, match=r"joint 'l_leg_kny' locked at 0 \(its limit\) instead of -1; limits"):
        robot = load_robot(ATLAS_V5, base="utorso", tip="l_hand", locked={"l_leg_kny": -1.0})
    assert robot.cut is not None and robot.cut.locked["l_leg_kny"] == 0.0


def test_bad_cuts_are_named(ur_arm: Path) -> None:
    with pytest.raises(ModelError, match="unknown tip link 'hand' in .*; links are: base_link, shoulder_link"):
        _quiet_load(ur_arm, tip="hand")
    with pytest.raises(ModelError, match="tip link 'shoulder_link' .* does not hang below base link 'forearm_link'"):
        _quiet_load(ur_arm, base="forearm_link", tip="shoulder_link")
    with pytest.raises(ModelError, match=r"joint\(s\) \['elbow_joint'\] are on the arm from 'base_link' to 'tool0'"):
        _quiet_load(ur_arm, tip=UR_LIKE_TIP, locked={"elbow_joint": 0.1})
    with pytest.raises(ModelError, match=r"cannot lock unknown joint\(s\) \['finger'\] .*; joints are: shoulder_pan"):
        _quiet_load(ur_arm, tip=UR_LIKE_TIP, locked={"finger": 0.1})
    with pytest.raises(ModelError, match="no joint moves between base link 'flange' and tip link 'tool0'"):
        _quiet_load(ur_arm, base="flange", tip=UR_LIKE_TIP)
    # a serial arm has nothing to lock: a lock names a joint of the arm itself
    with pytest.raises(ModelError, match=r"joint\(s\) \['panda_joint1'\] are on the arm from 'panda_link0' to"):
        load_robot("panda", locked={"panda_joint1": 0.1})


def test_load_arguments_rebuild_the_same_robot(ur_arm: Path) -> None:
    robot = _quiet_load(ur_arm, tip=UR_LIKE_TIP, locked={UR_LIKE_FINGERS[1]: 0.02})
    args = robot.load_arguments()
    assert args == {
        "ee_frame": UR_LIKE_TIP,
        "sensor_frame": UR_LIKE_TIP,
        "base": "base_link",
        "tip": UR_LIKE_TIP,
        "locked": {UR_LIKE_FINGERS[0]: 0.0, UR_LIKE_FINGERS[1]: 0.02},
    }
    again = _quiet_load(ur_arm, **args)
    np.testing.assert_array_equal(again.inertial_parameters(), robot.inertial_parameters())
    assert "base='base_link', tip='tool0'" in repr(robot)


# ---------------------------------------------------------------------- MJCF trees
@pytest.mark.skipif(not MENAGERIE.is_dir(), reason=f"Menagerie files not available at {MENAGERIE}")
@pytest.mark.parametrize("name", ["iiwa14.xml", "panda_nohand.xml"])
def test_menagerie_arms_still_load_whole(name: str) -> None:
    robot = _quiet_load(MENAGERIE / name, ee_frame="attachment_site" if "panda" in name else "link7")
    assert robot.n == 7 and robot.cut is None


@pytest.mark.skipif(not MENAGERIE.is_dir(), reason=f"Menagerie files not available at {MENAGERIE}")
def test_mjcf_cut_locks_at_the_home_keyframe() -> None:
    """Cut below link5 of the Menagerie Panda, joints 6 and 7 are held at the file's "home" keyframe; the
    loader's own check compares the cut model with MuJoCo's frozen model, and so does the plant."""
    key = ET.parse(MENAGERIE / "panda_nohand.xml").getroot().find("keyframe/key[@name='home']")
    assert key is not None
    home = [float(v) for v in key.get("qpos", "").split()]
    robot = _quiet_load(MENAGERIE / "panda_nohand.xml", tip="link5")
    assert robot.n == 5 and robot.cut is not None
    assert dict(robot.cut.locked) == {"joint6": home[5], "joint7": home[6]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        plant = Plant(robot, noise=SensorNoise.none())
    assert max(check_agreement(robot, plant, n_states=20).values()) <= ATOL
