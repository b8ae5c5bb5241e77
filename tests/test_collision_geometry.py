"""Link collision geometry: MuJoCo and Pinocchio place every point alike, points lie on their geom with
outward normals (MuJoCo's own ray casts), link membership, non-contact geoms, bad input."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from reflexarm.errors import ConfigError
from reflexarm.robots import load_robot, write_ur_like_arm
from reflexarm.robots.collision_geometry import compile_collision_model, link_collision_geometry


@pytest.fixture(scope="module")
def arms(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ur = load_robot(write_ur_like_arm(tmp_path_factory.mktemp("ur")), tip="tool0")
        return {"atlas": load_robot("atlas_v5_left_arm"), "panda": load_robot("panda"), "ur_like": ur}


def _geom_id(mj, name):
    return int(name.split("#")[1]) if "#" in name else mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, name)


@pytest.mark.parametrize("name", ["atlas", "panda", "ur_like"])
def test_mujoco_and_pinocchio_place_points_alike(arms, name):
    robot = arms[name]
    geometry = link_collision_geometry(robot)
    mj, qadr = compile_collision_model(robot)
    data = mujoco.MjData(mj)
    pdata = robot.pin_model.createData()
    rng = np.random.default_rng(0)
    lo = np.maximum(robot.lower_limit, -np.pi)
    hi = np.minimum(robot.upper_limit, np.pi)
    for _ in range(5):
        q = rng.uniform(lo, hi)
        data.qpos[:] = mj.qpos0
        data.qpos[qadr] = q
        mujoco.mj_kinematics(mj, data)
        pin.forwardKinematics(robot.pin_model, pdata, q)
        for s in geometry.links:
            oMi = pdata.oMi[s.joint + 1]
            for k, geom in enumerate(s.geoms):
                g = _geom_id(mj, geom)
                sel = s.geom_index == k
                by_mujoco = s.geom_points[sel] @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
                by_pinocchio = s.points[sel] @ oMi.rotation.T + oMi.translation
                # both are exact rigid transforms of the same numbers: round-off only
                np.testing.assert_allclose(by_pinocchio, by_mujoco, atol=1e-12, err_msg=f"{name} {geom}")


@pytest.mark.parametrize("name", ["atlas", "panda", "ur_like"])
def test_points_on_surface_with_outward_normals(arms, name):
    """A ray from 5 mm outside along -n hits the point's own geom after 5 mm (MuJoCo's own ray casts)."""
    robot = arms[name]
    geometry = link_collision_geometry(robot)
    mj, qadr = compile_collision_model(robot)
    data = mujoco.MjData(mj)
    q = robot.home.copy()
    data.qpos[:] = mj.qpos0
    data.qpos[qadr] = q
    mujoco.mj_kinematics(mj, data)
    pdata = robot.pin_model.createData()
    pin.forwardKinematics(robot.pin_model, pdata, q)
    rng = np.random.default_rng(1)
    for s in geometry.links:
        R_joint = pdata.oMi[s.joint + 1].rotation
        for i in rng.choice(s.size, size=min(s.size, 40), replace=False) if s.size else []:
            g = _geom_id(mj, s.geoms[s.geom_index[i]])
            p = data.geom_xmat[g].reshape(3, 3) @ s.geom_points[i] + data.geom_xpos[g]
            n = R_joint @ s.normals[i]
            start = p + 0.005 * n
            if mj.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                dist = mujoco.mj_rayMesh(mj, data, g, start, -n)
            else:
                dist = mujoco.mju_rayGeom(
                    data.geom_xpos[g], data.geom_xmat[g], mj.geom_size[g], start, -n, int(mj.geom_type[g])
                )
            assert dist == pytest.approx(0.005, abs=1e-6), (name, s.geoms[s.geom_index[i]])


def _world_points(robot, surface, q):
    data = robot.pin_model.createData()
    pin.forwardKinematics(robot.pin_model, data, q)
    oMi = data.oMi[surface.joint + 1]
    return surface.points @ oMi.rotation.T + oMi.translation


def test_atlas_links(arms):
    geometry = link_collision_geometry(arms["atlas"])
    assert geometry.links_without_geometry() == (4,)  # l_ufarm has no contact geom
    assert geometry.links[6].link_name == "l_hand"
    assert "l_tool" in geometry.links[6].bodies  # a fixed child body belongs to the joint before it
    assert geometry.links[6].geoms == ("l_tool_col",)
    names = {g for s in geometry.links for g in s.geoms}
    assert "utorso_vis" not in names


def test_spacing_and_no_interior_points(arms):
    geometry = link_collision_geometry(arms["panda"], spacing=0.01)
    link2 = geometry.links[1]  # two overlapping capsules
    assert link2.geoms == ("panda_link2_col", "panda_link2_arm_col")
    from scipy.spatial import cKDTree

    d, _ = cKDTree(link2.points).query(link2.points, k=2)
    assert 0.004 < np.median(d[:, 1]) < 0.012
    # no point of one capsule lies inside the other (distance to its axis segment >= its radius)
    mj, qadr = compile_collision_model(arms["panda"])
    data = mujoco.MjData(mj)
    q = np.zeros(7)
    q[3] = -1.0
    data.qpos[qadr] = q
    mujoco.mj_kinematics(mj, data)
    world = _world_points(arms["panda"], link2, q)
    for k in (0, 1):
        g = _geom_id(mj, link2.geoms[1 - k])
        local = (world[link2.geom_index == k] - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
        r, h = mj.geom_size[g][:2]
        axis = np.column_stack([np.zeros((local.shape[0], 2)), np.clip(local[:, 2], -h, h)])
        assert np.linalg.norm(local - axis, axis=1).min() >= r - 1e-6
    finer = link_collision_geometry(arms["panda"], spacing=0.005)
    assert finer.point_counts().sum() > 3 * geometry.point_counts().sum()


def test_non_contact_geoms_are_ignored(tmp_path):
    xml = tmp_path / "arm.xml"
    xml.write_text(
        """<mujoco><compiler angle="radian" inertiafromgeom="false"/><worldbody>
        <body name="l1"><joint name="j1" axis="0 0 1" range="-1 1"/>
          <inertial pos="0 0 0.1" mass="1" diaginertia="0.01 0.01 0.01"/>
          <geom name="vis" type="sphere" size="0.05" contype="0" conaffinity="0"/>
          <body name="l2" pos="0 0 0.2"><joint name="j2" axis="0 1 0" range="-1 1"/>
            <inertial pos="0 0 0.1" mass="1" diaginertia="0.01 0.01 0.01"/>
            <geom name="col" type="box" size="0.02 0.03 0.04"/>
            <site name="ee" pos="0 0 0.1"/></body></body></worldbody></mujoco>"""
    )
    robot = load_robot(xml, ee_frame="ee")
    geometry = link_collision_geometry(robot, spacing=0.01)
    assert geometry.links[0].size == 0 and geometry.links[0].geoms == ()
    assert geometry.links[1].geoms == ("col",)
    # box 4 x 6 x 8 cm at 1 cm cells: 2 (4*6 + 4*8 + 6*8) = 208 points
    assert geometry.links[1].size == 208


def test_bad_spacing(arms):
    with pytest.raises(ConfigError, match="spacing must be a positive number of metres; got -0.01"):
        link_collision_geometry(arms["panda"], spacing=-0.01)
