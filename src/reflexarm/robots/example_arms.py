"""Robot files reflexarm writes for examples and end-to-end tests: a UR5-like 6-DoF arm with a gripper.

:func:`write_ur_like_arm` writes a ROS-style description package, as a user's arm comes::

    FOLDER/ur_like_description/
        package.xml
        meshes/*.stl            small closed cylinders and boxes (binary STL)
        urdf/ur_like.urdf       package:// mesh URIs, ros2_control and gazebo tags, a <mujoco> block

The kinematics are the UR5's published ones (shoulder 0.089 m high, upper arm 0.425 m, forearm
0.392 m); masses are the UR5's, inertias those of solid cylinders of the link's size (physically
consistent by construction); effort/velocity limits like the UR5's; every joint has Coulomb + viscous
``<dynamics>``. A two-finger parallel gripper (two prismatic finger joints) hangs off ``tool0``: the file
is a tree, so the arm is loaded with ``tip="tool0"`` (``--tip tool0``), which locks the fingers (closed, 0 m)
and keeps the gripper's mass on the last link.

The ``<mujoco><compiler meshdir="../meshes"/></mujoco>`` block lets plain MuJoCo open the file
(``mujoco.MjModel.from_xml_path``; MuJoCo strips ``package://PKG/meshes/`` to the file name);
reflexarm resolves ``package://`` itself (see ``reflexarm.robots._urdf``).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["UR_LIKE_BASE", "UR_LIKE_JOINTS", "UR_LIKE_PACKAGE", "UR_LIKE_TIP", "write_ur_like_arm"]

UR_LIKE_PACKAGE = "ur_like_description"
#: Root link of the file and the arm's last link (the flange frame the gripper is mounted on).
UR_LIKE_BASE = "base_link"
UR_LIKE_TIP = "tool0"
#: The finger joints, locked when the arm is cut at :data:`UR_LIKE_TIP`.
UR_LIKE_FINGERS = ("gripper_left_finger_joint", "gripper_right_finger_joint")


@dataclass(frozen=True)
class _Link:
    """One moving link: the joint that moves it and a solid cylinder standing in for its body."""

    name: str
    joint: str
    origin_xyz: tuple[float, float, float]  # joint frame in the parent link frame [m]
    origin_rpy: tuple[float, float, float]  # [rad]
    mass: float  # [kg]
    radius: float  # cylinder radius [m]
    length: float  # cylinder length along `direction` [m]
    direction: str  # "x", "y" or "z": the link's long axis in its own frame
    effort: float  # [Nm]
    velocity: float  # [rad/s]
    limit: float  # symmetric position limit [rad]
    coulomb: float  # <dynamics friction> [Nm]
    viscous: float  # <dynamics damping> [Nm s/rad]


_HALF_PI = math.pi / 2
_LINKS = (
    # name, joint, origin xyz, origin rpy, mass, radius, length, direction, effort, velocity, limit, mu_C, d_v
    _Link("shoulder_link", "shoulder_pan_joint", (0, 0, 0.089159), (0, 0, 0),
          3.7, 0.06, 0.15, "z", 150, 3.15, 6.2832, 2.5, 0.8),
    _Link("upper_arm_link", "shoulder_lift_joint", (0, 0.13585, 0), (0, _HALF_PI, 0),
          8.393, 0.06, 0.425, "z", 150, 3.15, 6.2832, 2.5, 0.8),
    _Link("forearm_link", "elbow_joint", (0, -0.1197, 0.425), (0, 0, 0),
          2.275, 0.05, 0.39225, "z", 150, 3.15, 3.1416, 1.8, 0.5),
    _Link("wrist_1_link", "wrist_1_joint", (0, 0, 0.39225), (0, _HALF_PI, 0),
          1.219, 0.04, 0.093, "y", 28, 3.2, 6.2832, 0.6, 0.15),
    _Link("wrist_2_link", "wrist_2_joint", (0, 0.093, 0), (0, 0, 0),
          1.219, 0.04, 0.09465, "z", 28, 3.2, 6.2832, 0.6, 0.15),
    _Link("wrist_3_link", "wrist_3_joint", (0, 0, 0.09465), (0, 0, 0),
          0.1879, 0.0375, 0.0823, "y", 28, 3.2, 6.2832, 0.4, 0.1),
)  # fmt: skip
_AXES = {"shoulder_pan_joint": "0 0 1", "wrist_2_joint": "0 0 1"}  # the others turn about y
_NO_OFFSET = '<origin xyz="0 0 0"/>'
_BASE_MASS = 4.0  # [kg]
_GRIPPER_MASS = 0.45  # gripper body [kg]
_FINGER_MASS = 0.06  # each finger [kg]
_FINGER_STROKE = 0.04  # each finger opens 0..40 mm


def _f(values: tuple[float, ...] | list[float]) -> str:
    return " ".join(f"{v:.6g}" for v in values)


def _cylinder_inertia(mass: float, radius: float, length: float, direction: str) -> tuple[float, float, float]:
    """Diagonal inertia (xx, yy, zz) about the centre of a solid cylinder whose axis is ``direction``."""
    axial = 0.5 * mass * radius**2
    transverse = mass * (3 * radius**2 + length**2) / 12
    return tuple(axial if a == direction else transverse for a in "xyz")  # type: ignore[return-value]


def _axis_rpy(direction: str) -> str:
    """rpy that turns a mesh built along z onto ``direction``."""
    return {"x": f"0 {_HALF_PI:.6g} 0", "y": f"{-_HALF_PI:.6g} 0 0", "z": "0 0 0"}[direction]


def _inertial(mass: float, com: list[float], diag: tuple[float, float, float]) -> str:
    return (
        f'<inertial><origin xyz="{_f(com)}" rpy="0 0 0"/><mass value="{mass:.6g}"/>'
        f'<inertia ixx="{diag[0]:.6g}" ixy="0" ixz="0" iyy="{diag[1]:.6g}" iyz="0" izz="{diag[2]:.6g}"/></inertial>'
    )


def _mesh_elements(mesh: str, origin: str) -> str:
    uri = f"package://{UR_LIKE_PACKAGE}/meshes/{mesh}.stl"
    geometry = f'<geometry><mesh filename="{uri}"/></geometry>'
    return f"<visual>{origin}{geometry}</visual><collision>{origin}{geometry}</collision>"


def _urdf() -> str:
    out = ['<?xml version="1.0"?>', '<robot name="ur_like">']
    base_diag = _cylinder_inertia(_BASE_MASS, 0.075, 0.09, "z")
    out.append(
        f'  <link name="{UR_LIKE_BASE}">{_inertial(_BASE_MASS, [0, 0, 0.045], base_diag)}'
        f"{_mesh_elements('base', _NO_OFFSET)}</link>"
    )
    parent = UR_LIKE_BASE
    for link in _LINKS:
        com = [0.0, 0.0, 0.0]
        com["xyz".index(link.direction)] = link.length / 2
        diag = _cylinder_inertia(link.mass, link.radius, link.length, link.direction)
        origin = f'<origin xyz="0 0 0" rpy="{_axis_rpy(link.direction)}"/>'
        out.append(
            f'  <link name="{link.name}">{_inertial(link.mass, com, diag)}{_mesh_elements(link.name, origin)}</link>'
        )
        out.append(
            f'  <joint name="{link.joint}" type="revolute"><parent link="{parent}"/><child link="{link.name}"/>'
            f'<origin xyz="{_f(link.origin_xyz)}" rpy="{_f(link.origin_rpy)}"/>'
            f'<axis xyz="{_AXES.get(link.joint, "0 1 0")}"/>'
            f'<limit lower="{-link.limit:.6g}" upper="{link.limit:.6g}" effort="{link.effort:g}" '
            f'velocity="{link.velocity:g}"/><dynamics damping="{link.viscous:g}" friction="{link.coulomb:g}"/></joint>'
        )
        parent = link.name
    out.append(f'  <link name="flange"/><link name="{UR_LIKE_TIP}"/>')
    out.append(
        f'  <joint name="wrist_3-flange" type="fixed"><parent link="{parent}"/><child link="flange"/>'
        f'<origin xyz="0 0.0823 0" rpy="0 0 {_HALF_PI:.6g}"/></joint>'
    )
    out.append(
        f'  <joint name="flange-tool0" type="fixed"><parent link="flange"/><child link="{UR_LIKE_TIP}"/>'
        f'<origin xyz="0 0 0" rpy="{_HALF_PI:.6g} 0 {_HALF_PI:.6g}"/></joint>'
    )
    out.extend(_gripper())
    out.extend(_ros_tags())
    out.append(
        '  <mujoco><compiler meshdir="../meshes" strippath="true" discardvisual="false" fusestatic="false"/></mujoco>'
    )
    out.append("</robot>")
    return "\n".join(out) + "\n"


def _gripper() -> list[str]:
    """Gripper body on tool0 (its z axis points out of the flange) and two fingers opening along y."""
    body_diag = _cylinder_inertia(_GRIPPER_MASS, 0.04, 0.07, "z")
    finger_diag = _cylinder_inertia(_FINGER_MASS, 0.01, 0.05, "z")
    out = [
        f'  <link name="gripper_base_link">{_inertial(_GRIPPER_MASS, [0, 0, 0.035], body_diag)}'
        f"{_mesh_elements('gripper_base', _NO_OFFSET)}</link>",
        f'  <joint name="tool0-gripper" type="fixed"><parent link="{UR_LIKE_TIP}"/><child link="gripper_base_link"/>'
        '<origin xyz="0 0 0"/></joint>',
    ]
    for side, sign, joint in (("left", 1, UR_LIKE_FINGERS[0]), ("right", -1, UR_LIKE_FINGERS[1])):
        out.append(
            f'  <link name="gripper_{side}_finger">{_inertial(_FINGER_MASS, [0, 0, 0.025], finger_diag)}'
            f'<collision><origin xyz="0 0 0.025"/><geometry><box size="0.01 0.02 0.05"/></geometry></collision></link>'
        )
        out.append(
            f'  <joint name="{joint}" type="prismatic"><parent link="gripper_base_link"/>'
            f'<child link="gripper_{side}_finger"/><origin xyz="0 {sign * 0.01:g} 0.07"/><axis xyz="0 {sign} 0"/>'
            f'<limit lower="0" upper="{_FINGER_STROKE:g}" effort="20" velocity="0.1"/>'
            '<dynamics damping="5" friction="1"/></joint>'
        )
    return out


def _ros_tags() -> list[str]:
    joints = [link.joint for link in _LINKS]
    out = ['  <ros2_control name="ur_like_system" type="system">']
    out.append("    <hardware><plugin>mock_components/GenericSystem</plugin></hardware>")
    for joint in joints:
        out.append(
            f'    <joint name="{joint}"><command_interface name="effort"/><state_interface name="position"/>'
            '<state_interface name="velocity"/><state_interface name="effort"/></joint>'
        )
    out.append("  </ros2_control>")
    out.append('  <gazebo reference="base_link"><material>Gazebo/Grey</material></gazebo>')
    out.append(
        '  <gazebo><plugin filename="libgazebo_ros2_control.so" name="gazebo_ros2_control">'
        f"<parameters>$(find {UR_LIKE_PACKAGE})/config/controllers.yaml</parameters></plugin></gazebo>"
    )
    return out


# ---------------------------------------------------------------------- meshes
def _cylinder_triangles(radius: float, length: float, segments: int = 16) -> np.ndarray:
    """(n, 3, 3) outward-facing triangles of a closed cylinder from z=0 to z=length."""
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    tris = []
    for k in range(segments):
        (x0, y0), (x1, y1) = ring[k], ring[(k + 1) % segments]
        p00, p10, p01, p11 = (x0, y0, 0.0), (x1, y1, 0.0), (x0, y0, length), (x1, y1, length)
        tris += [(p00, p10, p11), (p00, p11, p01)]  # side
        tris += [((0.0, 0.0, 0.0), p10, p00), ((0.0, 0.0, length), p01, p11)]  # bottom (-z), top (+z)
    return np.asarray(tris, dtype=float)


def _write_stl(path: Path, triangles: np.ndarray) -> None:
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    with path.open("wb") as f:
        f.write(b"reflexarm example mesh".ljust(80, b" "))
        f.write(struct.pack("<I", len(triangles)))
        for n, t in zip(normals, triangles, strict=True):
            f.write(struct.pack("<12fH", *n, *t.reshape(-1), 0))


def write_ur_like_arm(folder: str | Path) -> Path:
    """Write the UR5-like arm's description package into ``folder``; returns the URDF's path.

    Load the arm with ``load_robot(path, tip="tool0")`` (``--robot PATH --tip tool0``): the end effector and
    the wrist sensor default to ``tool0``; the gripper's finger joints are locked closed.
    """
    package = Path(folder) / UR_LIKE_PACKAGE
    (package / "urdf").mkdir(parents=True, exist_ok=True)
    (package / "meshes").mkdir(exist_ok=True)
    (package / "package.xml").write_text(
        '<?xml version="1.0"?>\n<package format="3">\n'
        f"  <name>{UR_LIKE_PACKAGE}</name>\n  <version>0.1.0</version>\n"
        "  <description>UR5-like 6-DoF arm with a two-finger gripper, written by reflexarm</description>\n"
        '  <maintainer email="nobody@example.com">reflexarm</maintainer>\n  <license>BSD-3-Clause</license>\n'
        "  <buildtool_depend>ament_cmake</buildtool_depend>\n"
        "  <export><build_type>ament_cmake</build_type></export>\n</package>\n"
    )
    _write_stl(package / "meshes" / "base.stl", _cylinder_triangles(0.075, 0.09))
    _write_stl(package / "meshes" / "gripper_base.stl", _cylinder_triangles(0.04, 0.07))
    for link in _LINKS:
        _write_stl(package / "meshes" / f"{link.name}.stl", _cylinder_triangles(link.radius, link.length))
    path = package / "urdf" / "ur_like.urdf"
    path.write_text(_urdf())
    return path


#: The arm's joints, base to tip (0-based order of the loaded model).
UR_LIKE_JOINTS = tuple(link.joint for link in _LINKS)
