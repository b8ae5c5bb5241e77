"""Small arm files the identification tests write (until the project's 6-DoF generator lands).

:func:`write_six_dof_urdf` writes a UR5-like 6-DoF URDF (masses, COMs and inertias of the UR5's
published DH-based model, rounded; limits, Coulomb + viscous ``<dynamics>``; no meshes, box/cylinder
collision geometry) and :func:`write_six_dof_mjcf` the same arm as MJCF. Both load with ``load_robot``
and on the plant.
"""

from __future__ import annotations

from pathlib import Path

#: (name, parent offset xyz, axis, mass [kg], com xyz [m], diagonal inertia [kg m^2], friction [Nm], damping [Nms/rad])
SIX_DOF_LINKS = (
    ("shoulder_pan", (0.0, 0.0, 0.089), (0, 0, 1), 3.7, (0.0, -0.02, 0.0), (0.010, 0.010, 0.007), 1.2, 0.6),
    ("shoulder_lift", (0.0, 0.136, 0.0), (0, 1, 0), 8.4, (0.21, 0.0, 0.0), (0.023, 0.130, 0.130), 1.5, 0.8),
    ("elbow", (0.425, -0.12, 0.0), (0, 1, 0), 2.3, (0.19, 0.0, 0.0), (0.004, 0.031, 0.031), 0.9, 0.5),
    ("wrist_1", (0.392, 0.0, 0.0), (0, 1, 0), 1.2, (0.0, 0.09, 0.0), (0.002, 0.002, 0.002), 0.4, 0.2),
    ("wrist_2", (0.0, 0.093, 0.0), (0, 0, 1), 1.2, (0.0, 0.0, 0.09), (0.002, 0.002, 0.002), 0.4, 0.2),
    ("wrist_3", (0.0, 0.0, 0.095), (0, 1, 0), 0.19, (0.0, 0.06, 0.0), (0.0002, 0.0002, 0.0002), 0.2, 0.1),
)
#: The frame at the flange (a fixed child of the last link).
SIX_DOF_TOOL = "tool"
_EFFORT = (150, 150, 150, 28, 28, 28)
_VELOCITY = 3.15
_LIMIT = 3.1


def _vec(v: tuple[float, ...] | tuple[int, ...]) -> str:
    return " ".join(f"{x:g}" for x in v)


def six_dof_urdf() -> str:
    parts = ['<robot name="ur_like_6dof">', '  <link name="base_link"/>']
    parent = "base_link"
    for k, (name, off, axis, m, c, diag, fr, dmp) in enumerate(SIX_DOF_LINKS):
        link = f"{name}_link"
        parts.append(
            f'  <link name="{link}"><inertial><origin xyz="{_vec(c)}"/><mass value="{m:g}"/>'
            f'<inertia ixx="{diag[0]:g}" ixy="0" ixz="0" iyy="{diag[1]:g}" iyz="0" izz="{diag[2]:g}"/></inertial>'
            f'<collision><origin xyz="{_vec(c)}"/><geometry><sphere radius="0.04"/></geometry></collision></link>'
        )
        parts.append(
            f'  <joint name="{name}_joint" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="{_vec(off)}"/><axis xyz="{_vec(axis)}"/>'
            f'<limit lower="{-_LIMIT:g}" upper="{_LIMIT:g}" effort="{_EFFORT[k]}" velocity="{_VELOCITY:g}"/>'
            f'<dynamics friction="{fr:g}" damping="{dmp:g}"/></joint>'
        )
        parent = link
    parts.append(f'  <link name="{SIX_DOF_TOOL}"/>')
    parts.append(
        f'  <joint name="tool_fixed" type="fixed"><parent link="{parent}"/><child link="{SIX_DOF_TOOL}"/>'
        '<origin xyz="0 0.08 0"/></joint>'
    )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def six_dof_mjcf() -> str:
    body_open = []
    indent = "    "
    for k, (name, off, axis, m, c, diag, fr, dmp) in enumerate(SIX_DOF_LINKS):
        pad = indent * (k + 2)
        body_open.append(
            f'{pad}<body name="{name}_link" pos="{_vec(off)}">\n'
            f'{pad}  <inertial pos="{_vec(c)}" mass="{m:g}" diaginertia="{_vec(diag)}"/>\n'
            f'{pad}  <joint name="{name}_joint" axis="{_vec(axis)}" range="{-_LIMIT:g} {_LIMIT:g}" '
            f'frictionloss="{fr:g}" damping="{dmp:g}" actuatorfrcrange="-{_EFFORT[k]} {_EFFORT[k]}"/>\n'
            f'{pad}  <geom type="sphere" size="0.04" pos="{_vec(c)}" contype="0" conaffinity="0"/>'
        )
    pad = indent * (len(SIX_DOF_LINKS) + 2)
    tool = f'{pad}<site name="{SIX_DOF_TOOL}" pos="0 0.08 0"/>'
    closes = [f"{indent * (k + 2)}</body>" for k in reversed(range(len(SIX_DOF_LINKS)))]
    return (
        '<mujoco model="ur_like_6dof">\n  <compiler angle="radian"/>\n  <worldbody>\n'
        + "\n".join(body_open)
        + "\n"
        + tool
        + "\n"
        + "\n".join(closes)
        + "\n  </worldbody>\n</mujoco>\n"
    )


def write_six_dof_urdf(folder: Path, name: str = "ur_like_6dof.urdf") -> Path:
    """Write the 6-DoF URDF into ``folder``; its tool frame is :data:`SIX_DOF_TOOL`."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(six_dof_urdf())
    return path


def write_six_dof_mjcf(folder: Path, name: str = "ur_like_6dof.xml") -> Path:
    """Write the 6-DoF MJCF into ``folder``; its tool site is :data:`SIX_DOF_TOOL`."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(six_dof_mjcf())
    return path
