"""A revolute-prismatic-revolute arm written by the tests: a prismatic joint along an unaligned axis between two
revolute joints, the axes of those two a choice (the regressor tests keep them axis-aligned, the replay tests tilt
one and flip the other)."""

from __future__ import annotations


def rpr_urdf(j1_axis: str = "0 0 1", j3_axis: str = "0 1 0") -> str:
    """The arm's URDF with the revolute joints j1 and j3 about the given axes ("x y z")."""
    return f"""<?xml version="1.0"?>
<robot name="rpr">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0.1 0.02 0.3"/><mass value="2.0"/>
    <inertia ixx="0.05" ixy="0.001" ixz="0.002" iyy="0.04" iyz="0.003" izz="0.02"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.0 0.05 -0.1"/><mass value="1.5"/>
    <inertia ixx="0.02" ixy="0.0" ixz="0.001" iyy="0.03" iyz="0.0" izz="0.01"/></inertial></link>
  <link name="l3"><inertial><origin xyz="0.2 0.0 0.0"/><mass value="0.8"/>
    <inertia ixx="0.01" ixy="0.0" ixz="0.0" iyy="0.02" iyz="0.0" izz="0.02"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.2" rpy="0.3 0 0"/>
    <axis xyz="{j1_axis}"/><limit lower="-3" upper="3" effort="100" velocity="5"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/><origin xyz="0.1 0 0.4" rpy="0 0.4 0.2"/>
    <axis xyz="0.6 0 0.8"/><limit lower="-0.3" upper="0.3" effort="100" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0.1 0" rpy="0 0 0.5"/>
    <axis xyz="{j3_axis}"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
</robot>
"""
