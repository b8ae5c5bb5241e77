"""Robot files as vendors ship them (issue 18 items 4 and 12, issue 20 items 7 and 12): COLLADA meshes, a gripper
cut off with ``--tip``, a rounded pi, a ``<limit>`` without lower/upper, a file of inertials only.

Every file is written here (the vendor's own, Kinova's ``gen3_2f85.urdf``, is not committed; its ``.dae``
meshes read to the vendor's STL copies' bounding boxes, see the report of issue 18). References: MuJoCo's
compiled geometry against the box the test wrote, and the vertices against hand-computed transforms.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.robots import RobotFileWarning, link_collision_geometry, load_robot
from reflexarm.robots._collada import collada_vertices
from reflexarm.sim import Plant, SensorNoise
from reflexarm.sim._rendering import frame_scene

#: Vertices are written with 9 significant digits and MuJoCo stores them as float32 (~6e-8 relative):
#: 1e-6 m separates round-off from a misread transform or unit (>= 1e-3 m here).
ATOL_M = 1e-6

_BOX_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)


def box_dae(
    size_mm: tuple[float, float, float], *, translate_mm: tuple[float, float, float], rotate_z_deg: float
) -> str:
    """A COLLADA file in millimetres: a box of ``size_mm`` with one corner at the origin, placed by a node that
    translates, then turns about z (a Blender export has the same layout)."""
    verts = " ".join(f"{v:.9g}" for v in (_BOX_CORNERS * np.array(size_mm)).ravel())
    faces = "0 2 1 1 2 3 4 5 6 5 7 6 0 1 4 1 5 4 2 6 3 3 6 7 0 4 2 2 4 6 1 3 5 3 7 5"
    return f"""<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="millimeter" meter="0.001"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries><geometry id="box-mesh" name="box"><mesh>
    <source id="box-positions"><float_array id="box-positions-array" count="24">{verts}</float_array>
      <technique_common><accessor source="#box-positions-array" count="8" stride="3">
        <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
      </accessor></technique_common></source>
    <vertices id="box-vertices"><input semantic="POSITION" source="#box-positions"/></vertices>
    <triangles count="12"><input semantic="VERTEX" source="#box-vertices" offset="0"/><p>{faces}</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="Scene" name="Scene">
    <node id="box" name="box" type="NODE">
      <translate sid="location">{" ".join(f"{v:g}" for v in translate_mm)}</translate>
      <rotate sid="rotationZ">0 0 1 {rotate_z_deg:g}</rotate>
      <instance_geometry url="#box-mesh" name="box"/>
    </node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#Scene"/></scene>
</COLLADA>
"""


def _inertial(mass: float, xyz: str = "0 0 0") -> str:
    return (
        f'<inertial><origin xyz="{xyz}"/><mass value="{mass}"/>'
        '<inertia ixx="0.004" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.002"/></inertial>'
    )


def vendor_like_urdf(mesh: str, *, limits: str = 'lower="-2.4" upper="2.4"') -> str:
    """A 3-DoF arm as Kinova's file is: a ``3.1416`` base rotation, ``.dae`` collision meshes (``mesh`` on the
    first two links), a continuous joint, and a Robotiq-like gripper whose right knuckle mimics the left."""
    collision = f'<collision><geometry><mesh filename="{mesh}"/></geometry></collision>'
    return f"""<robot name="vendor_like">
  <link name="world"/>
  <link name="base_link">{_inertial(1.0, "0 0 0.05")}</link>
  <link name="shoulder">{_inertial(1.2, "0 0 0.1")}{collision}</link>
  <link name="upper_arm">{_inertial(1.0, "0 0 0.15")}{collision}</link>
  <link name="forearm">{_inertial(0.8, "0 0 0.1")}</link>
  <link name="end_effector_link"/>
  <link name="gripper_base">{_inertial(0.3, "0 0 0.03")}</link>
  <link name="left_knuckle">{_inertial(0.03, "0 0 0.02")}</link>
  <link name="right_knuckle">{_inertial(0.03, "0 0 0.02")}</link>
  <joint name="base_joint" type="fixed"><parent link="world"/><child link="base_link"/></joint>
  <joint name="joint_1" type="continuous"><parent link="base_link"/><child link="shoulder"/>
    <origin xyz="0 0 0.15" rpy="3.1416 0 0"/><axis xyz="0 0 1"/><limit effort="39" velocity="1.4"/></joint>
  <joint name="joint_2" type="revolute"><parent link="shoulder"/><child link="upper_arm"/>
    <origin xyz="0 0.005 -0.13" rpy="1.5708 0 0"/><axis xyz="0 0 1"/>
    <limit effort="39" {limits} velocity="1.4"/></joint>
  <joint name="joint_3" type="revolute"><parent link="upper_arm"/><child link="forearm"/>
    <origin xyz="0 -0.41 0" rpy="3.1416 0 0"/><axis xyz="0 0 1"/>
    <limit effort="39" lower="-2.6" upper="2.6" velocity="1.4"/></joint>
  <joint name="end_effector" type="fixed"><parent link="forearm"/><child link="end_effector_link"/>
    <origin xyz="0 0 -0.2"/></joint>
  <joint name="gripper_mount" type="fixed"><parent link="end_effector_link"/><child link="gripper_base"/></joint>
  <joint name="left_knuckle_joint" type="revolute"><parent link="gripper_base"/><child link="left_knuckle"/>
    <origin xyz="0.03 0 0.05"/><axis xyz="0 -1 0"/><limit effort="50" lower="0" upper="0.8" velocity="0.5"/></joint>
  <joint name="right_knuckle_joint" type="revolute"><parent link="gripper_base"/><child link="right_knuckle"/>
    <origin xyz="-0.03 0 0.05"/><axis xyz="0 -1 0"/><limit effort="50" lower="-0.8" upper="0" velocity="0.5"/>
    <mimic joint="left_knuckle_joint" multiplier="-1"/></joint>
</robot>
"""


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def _quiet(call, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        return call(*args, **kwargs)


# ---------------------------------------------------------------------- COLLADA meshes (issue 18 item 4)
def test_collada_vertices_in_metres_placed_by_the_scene(tmp_path: Path) -> None:
    path = _write(tmp_path, "box.dae", box_dae((40, 60, 100), translate_mm=(10, -20, 5), rotate_z_deg=90))
    corners = _BOX_CORNERS * [0.04, 0.06, 0.1]
    turned = corners @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T  # 90 deg about z
    np.testing.assert_allclose(collada_vertices(path), turned + [0.01, -0.02, 0.005], atol=ATOL_M)


def test_dae_collision_meshes_are_in_the_plant_with_their_geometry(tmp_path: Path) -> None:
    _write(tmp_path, "box.dae", box_dae((40, 60, 100), translate_mm=(0, 0, 0), rotate_z_deg=0))
    path = _write(tmp_path, "arm.urdf", vendor_like_urdf("box.dae"))
    with pytest.warns(RobotFileWarning, match=r"1 COLLADA \(.dae\) collision mesh\(es\) \(box.dae\) given to MuJoCo"):
        robot = load_robot(path, tip="end_effector_link")
    plant = _quiet(Plant, robot, noise=SensorNoise.none())  # failed: "no decoder found for mesh file"
    m = plant.model
    meshes = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert {m.body(int(m.geom_bodyid[g])).name for g in meshes} == {"shoulder", "upper_arm"}
    for g in meshes:  # the box the file holds: half sides 20, 30, 50 mm
        np.testing.assert_allclose(m.geom_aabb[g, 3:], [0.02, 0.03, 0.05], atol=ATOL_M)
    geometry = _quiet(link_collision_geometry, robot, spacing=0.01)
    assert geometry.links[0].geoms and geometry.links[0].has_geometry


@pytest.mark.parametrize(
    ("name", "content", "problem"),
    [
        ("broken.dae", "<COLLADA><library_geometries>", r"cannot read the COLLADA mesh .*broken.dae"),
        ("shape.ply", "ply\nformat ascii 1.0\nend_header\n", r"shape.ply: MuJoCo reads STL, OBJ and MSH meshes"),
    ],
)
def test_a_mesh_that_cannot_be_read_is_dropped_with_a_warning(tmp_path: Path, name, content, problem) -> None:
    _write(tmp_path, name, content)
    path = _write(tmp_path, "arm.urdf", vendor_like_urdf(name))
    with pytest.warns(RobotFileWarning, match=rf"1 mesh file\(s\) cannot be read \({problem}"):
        robot = load_robot(path, tip="end_effector_link")
    plant = _quiet(Plant, robot, noise=SensorNoise.none())
    assert plant.model.geom("shoulder_inertia_box").type == mujoco.mjtGeom.mjGEOM_BOX


# ---------------------------------------------------------------------- once per file (issue 18 item 12)
def test_each_note_is_printed_once_per_command(tmp_path: Path) -> None:
    """As a user runs it (its own process, the default warning filters): each note of the file once, though
    the robot is loaded and its plants built several times (the controller's model, the geometry plant,
    the run's plant, the collision geometry)."""
    _write(tmp_path, "box.dae", box_dae((40, 60, 100), translate_mm=(0, 0, 0), rotate_z_deg=0))
    path = _write(tmp_path, "arm.urdf", vendor_like_urdf("box.dae"))
    argv = ["simulate", "link-collision", "--robot", str(path), "--tip", "end_effector_link", "--ee-frame",
            "left_knuckle", "--out", str(tmp_path / "out"), "--quiet"]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    done = subprocess.run([sys.executable, "-m", "reflexarm.cli", *argv], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [line for line in done.stderr.splitlines() if "RobotFileWarning" in line]
    assert any("COLLADA" in line for line in lines) and any("lies past the tip link" in line for line in lines), lines
    assert len(lines) == len(set(lines)), "\n".join(lines)


def test_a_note_is_given_once_though_the_filters_changed_between_two_loads(tmp_path: Path) -> None:
    """Python's default action forgets what it showed when any code enters ``catch_warnings`` (the experiments'
    geometry plant does, between loading the robot and building the run's plant): the note came again."""
    path = _write(tmp_path, "arm.urdf", vendor_like_urdf("missing.dae"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        load_robot(path, tip="end_effector_link")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RobotFileWarning)
        load_robot(path, tip="end_effector_link")
    texts = [str(w.message) for w in caught if issubclass(w.category, RobotFileWarning)]
    assert any("1 mesh file(s) not found" in t for t in texts), texts
    assert len(texts) == len(set(texts)), texts


# ---------------------------------------------------------------------- limits (issue 20 item 7)
def test_a_limit_without_lower_and_upper_is_unbounded_in_both_models_with_a_warning(tmp_path: Path) -> None:
    _write(tmp_path, "box.dae", box_dae((40, 60, 100), translate_mm=(0, 0, 0), rotate_z_deg=0))
    path = _write(tmp_path, "arm.urdf", vendor_like_urdf("box.dae", limits=""))
    with pytest.warns(
        RobotFileWarning,
        match=r"joint 'joint_2' has a <limit> without lower and upper, which URDF reads as 0 \(a range of \[0, 0\]: "
        r"the joint could not move\); the controller's model and the plant take it as unbounded both ways",
    ):
        robot = load_robot(path, tip="end_effector_link")
    np.testing.assert_array_equal(robot.lower_limit, [-np.inf, -np.inf, -2.6])  # was [.., 0, ..]
    np.testing.assert_array_equal(robot.upper_limit, [np.inf, np.inf, 2.6])
    np.testing.assert_array_equal(robot.effort_limit, [39.0, 39.0, 39.0])
    plant = _quiet(Plant, robot, noise=SensorNoise.none())
    assert not plant.model.jnt_limited[plant.model.joint("joint_2").id]  # MuJoCo's reading: no limit either


# ---------------------------------------------------------------------- inertials only (issue 20 item 12)
INERTIALS_ONLY = """<robot name="bare">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0 0 0.1"/><mass value="2"/>
    <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.005"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0 0"/><mass value="1.5"/>
    <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.012" iyz="0" izz="0.012"/></inertial></link>
  <link name="l3"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.005"/></inertial></link>
  <link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="60" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="60" velocity="2"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="30" velocity="2"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.2 0 0"/></joint>
</robot>
"""


def test_a_file_of_inertials_only_runs_a_closed_loop_command_with_its_still(tmp_path: Path) -> None:
    path = _write(tmp_path, "bare.urdf", INERTIALS_ONLY)
    out = tmp_path / "out"
    code = _quiet(main, ["simulate", "link-collision", "--robot", str(path), "--ee-frame", "tool", "--out", str(out),
                         "--quiet"])  # fmt: skip
    assert code == 0  # exited 2: "the plant has no finite geometry to frame"
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["contact_start_s"] is not None  # the stick meets the links' stand-in boxes
    assert (out / "link_collision_still.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


NO_GEOMETRY_MJCF = """<mujoco model="no_geometry">
  <worldbody>
    <body name="l1" pos="0 0 0.2"><joint name="j1" axis="0 0 1" range="-3 3"/>
      <inertial pos="0 0 0.1" mass="2" diaginertia="0.02 0.02 0.005"/>
      <body name="l2" pos="0 0 0.2"><joint name="j2" axis="0 1 0" range="-2 2"/>
        <inertial pos="0.15 0 0" mass="1" diaginertia="0.002 0.01 0.01"/><site name="tip" pos="0.3 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_a_plant_without_any_geometry_is_framed_by_its_bodies(tmp_path: Path) -> None:
    robot = _quiet(load_robot, _write(tmp_path, "arm.xml", NO_GEOMETRY_MJCF), ee_frame="tip")
    plant = _quiet(Plant, robot, noise=SensorNoise.none())
    assert plant.model.ngeom == 0
    view = frame_scene(plant)  # raised SimulationError("... no finite geometry to frame ...")
    assert all(math.isfinite(v) for v in (*view.lookat, view.distance))
    np.testing.assert_allclose(view.lookat[2], 0.2, atol=1e-9)  # the box of the origins: world 0, bodies 0.2, 0.4 m


# ---------------------------------------------------------------------- block placement (issue 18 items 4, 10)
def test_the_block_placement_sees_how_low_each_link_reaches(tmp_path: Path) -> None:
    """The placement's swept pieces reach at least as low as the plant's geometry itself: every corner of
    each box and every vertex of each mesh hull, in MuJoCo's world at the same postures (spheres around a
    box's or mesh's long axis stayed up to 3.3 cm above it on the Atlas arm, more than the clearance)."""
    from reflexarm.experiments.any_arm import ee_swing_plan, geometry_plant, up_direction
    from reflexarm.experiments.block_placement import SPHERES_PER_GEOM, _arm_geoms_along

    _write(tmp_path, "box.dae", box_dae((40, 60, 100), translate_mm=(0, 0, 0), rotate_z_deg=0))
    robot = _quiet(load_robot, _write(tmp_path, "arm.urdf", vendor_like_urdf("box.dae")), tip="end_effector_link")
    traj = ee_swing_plan(robot).trajectory()
    qs = np.array([traj.sample(float(t)).q_d for t in np.linspace(0.0, traj.duration, 20)])
    centres, halves, _, _ = _arm_geoms_along(robot, qs)
    up = up_direction(robot)
    reached = (centres @ up - np.abs(halves) @ np.abs(up)).reshape(len(qs), -1, SPHERES_PER_GEOM).min(axis=2)
    plant = _quiet(geometry_plant, robot)
    m, d = plant.model, plant.data
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] in plant._arm_bodies and m.geom_contype[g]]
    kinds = {int(m.geom_type[g]) for g in geoms}
    assert kinds == {int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_MESH)}, kinds
    short = np.zeros((len(qs), len(geoms)))  # how far each piece set stays above its geom's lowest point [m]
    for k, q in enumerate(qs):
        d.qpos[plant._qadr_arr] = q
        mujoco.mj_kinematics(m, d)
        for i, g in enumerate(geoms):
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                start, count = m.mesh_vertadr[m.geom_dataid[g]], m.mesh_vertnum[m.geom_dataid[g]]
                local = np.asarray(m.mesh_vert[start : start + count], dtype=float)
            else:
                local = (2.0 * _BOX_CORNERS - 1.0) * m.geom_size[g]
            short[k, i] = reached[k, i] - float(np.min((local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]) @ up))
    worst = np.unravel_index(np.argmax(short), short.shape)
    assert short.max() <= ATOL_M, f"geom {geoms[worst[1]]} at posture {worst[0]}: {short.max():.4f} m above it"
