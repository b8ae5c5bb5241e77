"""``reflexarm robots``: list the built-in robots, describe a robot, or list the frames of a robot file."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from reflexarm.robots.robot_model import RobotModel


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``robots`` to the top-level parser."""
    p = sub.add_parser(
        "robots",
        help="list the built-in robots, or describe one (or a URDF/MJCF file; without --ee-frame/--tip: its frames)",
    )
    p.add_argument("robot", nargs="?", help="built-in name or path to a .urdf/.xml file")
    p.add_argument("--ee-frame", help="end-effector frame (user files; default: the tip link)")
    p.add_argument("--sensor-frame", help="wrist force/torque sensor frame (default: the ee frame)")
    p.add_argument("--base", default=None, help="link the arm starts from, to cut an arm out of a tree (humanoid)")
    p.add_argument("--tip", default=None, help="last link of the arm, to cut it out of a tree (e.g. drop a gripper)")
    p.add_argument(
        "--lock",
        action="append",
        default=[],
        metavar="JOINT=VALUE",
        help="position [rad or m] at which a joint outside the base..tip chain is locked (repeatable; default 0)",
    )
    p.set_defaults(func=_robots)


def _robots(args: argparse.Namespace) -> int:
    from reflexarm._cli.robot_options import load_robot_from_args
    from reflexarm.robots import builtin_robots

    if args.robot is None:
        for name, b in sorted(builtin_robots().items()):
            print(f"{name:20s} {b.description}")
        return 0
    if args.robot not in builtin_robots() and args.ee_frame is None and args.tip is None:
        _print_frames(args.robot)
        return 0
    r = load_robot_from_args(args)
    np.set_printoptions(precision=4, suppress=True)
    print(r)
    if r.cut is not None:
        locked = ", ".join(f"{k}={v:g}" for k, v in r.cut.locked.items()) or "none"
        print(f"cut:           base {r.cut.base!r}, tip {r.cut.tip!r}; locked joints: {locked}")
    print(f"joints:        {', '.join(f'{i}:{name}' for i, name in enumerate(r.joint_names, start=1))}")
    print(f"lower [rad]:   {r.lower_limit}")
    print(f"upper [rad]:   {r.upper_limit}")
    print(f"velocity lim:  {r.velocity_limit}")
    print(f"effort lim:    {r.effort_limit}")
    print(f"Coulomb [Nm]:  {r.friction.coulomb}")
    print(f"viscous:       {r.friction.viscous}")
    print(f"total mass:    {r.inertial_parameters()[0::10].sum():.4f} kg (moving links, incl. what they carry)")
    print(_law_line(r))
    return 0


def _law_line(r: RobotModel) -> str:
    """The impedance law at the experiments' 300 Nm/rad, d_xi 0.7 and 1 kHz: its highest mode against its limit."""
    from reflexarm.control.law_stability import rate_limited_stiffness, worst_mode

    k, d, dt = np.full(r.n, 300.0), np.full(r.n, 0.7), 1e-3
    worst = worst_mode(r, k, d, dt)
    line = (
        f"law (2) at 300 Nm/rad, 1 kHz: highest mode omega dt = {worst.omega_dt:.3g}, {worst.share:.2f} of its "
        f"stability limit (joint {worst.joint + 1} {r.joint_names[worst.joint]})"
    )
    if worst.share < 1.0:
        return line
    capped, lowered = rate_limited_stiffness(r, k, d, dt)
    changes = ", ".join(f"{r.joint_names[j]} {capped[j]:.3g}" for j in lowered)
    return f"{line}: UNSTABLE; the experiments lower the stiffness [Nm/rad] of {changes} (about: on their model)"


def _print_frames(path: str) -> None:
    """The file's links as a tree: the choices for --base, --tip and --ee-frame."""
    from reflexarm.robots.frames import list_frames

    frames = list_frames(path)
    print(f"{path}: {sum(f.kind == 'link' for f in frames)} links; choose --ee-frame (and --tip/--base for a tree):")
    rows = []
    for f in frames:
        joint = f.joint or ("(root)" if f.parent is None else f"(fixed on {f.parent})")
        note = "leaf" if f.is_leaf else f"branch ({f.children} links)" if f.is_branch else ""
        if f.kind == "frame":
            note = f"frame on link {f.parent}"
        rows.append(("  " * min(f.depth, 10) + f.name, joint, str(f.depth), note))
    w0 = max(len("frame"), *(len(r[0]) for r in rows))
    w1 = max(len("moved by joint"), *(len(r[1]) for r in rows))
    print(f"  {'frame':{w0}s}  {'moved by joint':{w1}s}  joints from root  note")
    for name, joint, depth, note in rows:
        print(f"  {name:{w0}s}  {joint:{w1}s}  {depth:>16s}  {note}".rstrip())
    branches = [f.name for f in frames if f.is_branch]
    if branches:
        print(f"the file is a tree (branches at {', '.join(branches)}): cut the arm with --tip LINK [--base LINK]")
