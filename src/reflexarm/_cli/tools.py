"""``reflexarm robots``: list the built-in robots and describe a robot file."""

from __future__ import annotations

import argparse

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``robots`` to the top-level parser."""
    p = sub.add_parser("robots", help="list the built-in robots, or describe one (or a URDF/MJCF file)")
    p.add_argument("robot", nargs="?", help="built-in name or path to a .urdf/.xml file")
    p.add_argument("--ee-frame", help="end-effector frame (user files)")
    p.add_argument("--sensor-frame", help="wrist force/torque sensor frame (user files)")
    p.set_defaults(func=_robots)


def _robots(args: argparse.Namespace) -> int:
    from reflexarm.robots import builtin_robots, load_robot

    if args.robot is None:
        for name, b in sorted(builtin_robots().items()):
            print(f"{name:20s} {b.description}")
        return 0
    r = load_robot(args.robot, ee_frame=args.ee_frame, sensor_frame=args.sensor_frame)
    np.set_printoptions(precision=4, suppress=True)
    print(r)
    print(f"joints:        {', '.join(r.joint_names)}")
    print(f"lower [rad]:   {r.lower_limit}")
    print(f"upper [rad]:   {r.upper_limit}")
    print(f"velocity lim:  {r.velocity_limit}")
    print(f"effort lim:    {r.effort_limit}")
    print(f"Coulomb [Nm]:  {r.friction.coulomb}")
    print(f"viscous:       {r.friction.viscous}")
    print(f"total mass:    {r.inertial_parameters()[0::10].sum():.4f} kg")
    return 0
