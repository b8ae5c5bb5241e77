"""A Kinova-Gen3-like 7-DoF arm file the identification tests write (kinematics, masses and inertias of
the vendor's ``gen3.urdf`` from ``Kinovarobotics/ros2_kortex``, rounded; no meshes, capsule-like cylinder
collision geometry).

The vendor file gives joint 1 ``rpy="3.1416 ..."``: pi rounded to 4 decimals, which tilts joint 1's axis
by 7.3e-6 rad away from the vertical. :func:`gen3_like_urdf` writes that rounding with ``rounded_pi=True``
and the exact pi otherwise.
"""

from __future__ import annotations

import math
from pathlib import Path

#: (joint, origin xyz, origin roll, lower, upper, effort [Nm], link, mass [kg], com xyz,
#:  inertia (ixx, ixy, ixz, iyy, iyz, izz) [kg m^2], collision cylinder (radius, length) [m])
GEN3_LINKS = (
    ("joint_1", (0, 0, 0.15643), math.pi, None, None, 39, "shoulder_link", 1.3773,
     (-2.3e-05, -0.010364, -0.07336), (0.00457, 1e-06, 2e-06, 0.004831, 0.000448, 0.001409), (0.045, 0.13)),
    ("joint_2", (0, 0.005375, -0.12838), math.pi / 2, -2.41, 2.41, 39, "half_arm_1_link", 1.1636,
     (-4.4e-05, -0.09958, -0.013278), (0.011088, 5e-06, 0, 0.001072, -0.000691, 0.011255), (0.045, 0.2)),
    ("joint_3", (0, -0.21038, -0.006375), -math.pi / 2, None, None, 39, "half_arm_2_link", 1.1636,
     (-4.4e-05, -0.006641, -0.117892), (0.010932, 0, -7e-06, 0.011127, 0.000606, 0.001043), (0.045, 0.2)),
    ("joint_4", (0, 0.006375, -0.21038), math.pi / 2, -2.66, 2.66, 39, "forearm_link", 0.9302,
     (-1.8e-05, -0.075478, -0.015006), (0.008147, -1e-06, 0, 0.000631, -0.0005, 0.008316), (0.04, 0.2)),
    ("joint_5", (0, -0.20843, -0.006375), -math.pi / 2, None, None, 9, "spherical_wrist_1_link", 0.6781,
     (1e-06, -0.009432, -0.063883), (0.001596, 0, 0, 0.001607, 0.000256, 0.000399), (0.035, 0.1)),
    ("joint_6", (0, 0.00017505, -0.10593), math.pi / 2, -2.23, 2.23, 9, "spherical_wrist_2_link", 0.6781,
     (1e-06, -0.045483, -0.00965), (0.001641, 0, 0, 0.00041, -0.000278, 0.001641), (0.035, 0.1)),
    ("joint_7", (0, -0.10593, -0.00017505), -math.pi / 2, None, None, 9, "bracelet_link", 0.364,
     (-9.3e-05, 0.000132, -0.022905), (0.000214, 0, 1e-06, 0.000223, -2e-06, 0.00024), (0.035, 0.06)),
)  # fmt: skip
#: Joint velocity limit of every joint [rad/s] (the vendor's 80 deg/s).
GEN3_VELOCITY = 1.3963
#: The end-effector frame (a fixed child of the bracelet link).
GEN3_TIP = "end_effector_link"


def gen3_like_urdf(*, rounded_pi: bool, continuous: bool = False) -> str:
    """The arm's URDF; joint 1's roll is ``3.1416`` (as the vendor's) if ``rounded_pi`` else exact pi.

    ``continuous``: joints 1, 3, 5, 7 unbounded as in the vendor file; otherwise revolute within +-pi.
    """
    out = ['<?xml version="1.0"?>', '<robot name="gen3_like">']
    out.append(
        '  <link name="base_link"><inertial><origin xyz="-0.000648 -0.000166 0.084487"/><mass value="1.697"/>'
        '<inertia ixx="0.004622" ixy="9e-06" ixz="6e-05" iyy="0.004495" iyz="9e-06" izz="0.002079"/></inertial>'
        '<collision><origin xyz="0 0 0.07"/><geometry><cylinder radius="0.05" length="0.14"/></geometry>'
        "</collision></link>"
    )
    parent = "base_link"
    for joint, xyz, roll, lo, hi, effort, link, mass, com, inertia, (radius, length) in GEN3_LINKS:
        r = "3.1416" if (rounded_pi and joint == "joint_1") else f"{roll:.17g}"
        ixx, ixy, ixz, iyy, iyz, izz = inertia
        out.append(
            f'  <link name="{link}"><inertial><origin xyz="{" ".join(f"{c:g}" for c in com)}"/>'
            f'<mass value="{mass:g}"/><inertia ixx="{ixx:g}" ixy="{ixy:g}" ixz="{ixz:g}" iyy="{iyy:g}" '
            f'iyz="{iyz:g}" izz="{izz:g}"/></inertial>'
            f'<collision><origin xyz="{" ".join(f"{c:g}" for c in com)}"/>'
            f'<geometry><cylinder radius="{radius:g}" length="{length:g}"/></geometry></collision></link>'
        )
        kind = "continuous" if (lo is None and continuous) else "revolute"
        lo, hi = (-math.pi, math.pi) if lo is None else (lo, hi)
        limit = f'<limit effort="{effort}" velocity="{GEN3_VELOCITY}"'
        limit += "/>" if kind == "continuous" else f' lower="{lo:g}" upper="{hi:g}"/>'
        out.append(
            f'  <joint name="{joint}" type="{kind}"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="{" ".join(f"{c:g}" for c in xyz)}" rpy="{r} 0 0"/><axis xyz="0 0 1"/>{limit}'
            '<dynamics damping="0.1" friction="0.3"/></joint>'
        )
        parent = link
    out.append(f'  <link name="{GEN3_TIP}"/>')
    out.append(
        f'  <joint name="end_effector" type="fixed"><parent link="{parent}"/><child link="{GEN3_TIP}"/>'
        f'<origin xyz="0 0 -0.061525" rpy="{math.pi:.17g} 0 0"/></joint>'
    )
    out.append("</robot>")
    return "\n".join(out) + "\n"


def write_gen3_like_urdf(folder: Path, *, rounded_pi: bool, continuous: bool = False) -> Path:
    """Write :func:`gen3_like_urdf` to ``folder/gen3_like{_3p1416}.urdf`` and return its path."""
    path = Path(folder) / f"gen3_like{'_3p1416' if rounded_pi else ''}.urdf"
    path.write_text(gen3_like_urdf(rounded_pi=rounded_pi, continuous=continuous))
    return path
