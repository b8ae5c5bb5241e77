"""``reflexarm identify friction`` (Sec. II-D 2, Fig. 4, Table I): single-joint constant-velocity runs.

The runs come from the user's logs (``--run JOINT=LOG``) or are simulated on the plant with the impedance
controller; each joint's friction points are fitted (:mod:`reflexarm.ident.friction.joint_friction`) and written
to ``--out`` as friction.json, friction.csv, friction_points.csv and Fig. 4. With ``--log`` (ordinary motion)
the command hands over to :func:`reflexarm._cli.identify_payload.friction_from_motion_command`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from reflexarm._cli.common import format_table, out_dir
from reflexarm._cli.ident_common import (
    friction_file,
    load_robot_arg,
    parse_floats,
    parse_joints,
    say,
    write_csv,
    write_json,
)
from reflexarm._cli.identify_payload import friction_from_motion_command
from reflexarm._cli.log_options import load_log_from_args
from reflexarm.errors import ConfigError

if TYPE_CHECKING:
    from reflexarm.ident.friction.joint_friction import FrictionFit


def identify_friction_command(args: argparse.Namespace) -> int:
    """Fit the runs (logged or simulated) and write the results; with ``--log``, friction from ordinary motion."""
    if args.log:  # ordinary motion: no constant-velocity runs needed
        if args.run:
            raise ConfigError("give --run JOINT=LOG (constant-velocity runs) or --log LOG (ordinary motion), not both")
        return friction_from_motion_command(args)
    out = out_dir(args)
    robot = load_robot_arg(args)
    truth = None
    if args.run:
        fits, friction = _fit_logged_runs(args, robot)
        why_missing = "have no run (--run)"
    else:
        fits, friction, truth, why_missing = _simulate_friction_runs(args, robot)
    rows = _friction_rows(robot, fits, truth)
    _write_friction(out, robot, fits, friction, rows, truth, why_missing)
    return 0


def _fit_logged_runs(args: argparse.Namespace, robot: Any) -> tuple[list[FrictionFit], Any]:
    """One friction fit per ``--run JOINT=LOG``: the log's constant-velocity intervals of that joint."""
    from reflexarm.ident.friction.joint_friction import (
        fit_friction,
        friction_from_fits,
        friction_points,
        segment_constant_velocity,
    )

    fits: list[FrictionFit] = []
    for spec in args.run:
        if "=" not in spec:
            raise ConfigError(f"--run expects JOINT=LOG (e.g. 3=runs_j3.csv); got {spec!r}")
        js, path = spec.split("=", 1)
        joints = parse_joints(js, robot.n)
        if len(joints) != 1:
            raise ConfigError(f"--run expects one joint per log (JOINT=LOG, e.g. 3=runs_j3.csv); got {spec!r}")
        j = joints[0]
        if any(ft.joint == j for ft in fits):
            raise ConfigError(f"--run: joint {j + 1} has two logs ({spec!r} and an earlier one); give one per joint")
        log = load_log_from_args(args, path, robot)
        from reflexarm.ident import preprocess_log

        proc = preprocess_log(log)
        intervals = segment_constant_velocity(proc.t, proc.dq[:, j], q=proc.q[:, j])
        if not intervals:
            raise ConfigError(
                f"{Path(path).name}: no constant-velocity interval of joint {j + 1} found; for a log of ordinary "
                f"motion give it as --log {path} (friction from the combined regression)"
            )
        pts = friction_points(robot, j, proc.t, proc.q, proc.dq, proc.tau, intervals)
        fits.append(fit_friction(pts, offset=not args.no_offset, robot=robot))
    # friction_from_fits puts 0 for the joints without a run: mark them not identified instead
    return fits, friction_from_fits(fits, robot.n).restricted_to([ft.joint for ft in fits])


def _simulate_friction_runs(
    args: argparse.Namespace, robot: Any
) -> tuple[list[FrictionFit], Any, tuple[np.ndarray, np.ndarray], str]:
    """The constant-velocity runs simulated on the plant: fits, friction, the plant's (mu_C, d_v), why some are
    missing."""
    from reflexarm.experiments.identification import hydraulic_joints, run_friction_experiments, scenario_extra
    from reflexarm.robots import perturb_model

    joints = parse_joints(args.joints, robot.n) if args.joints else list(hydraulic_joints(robot) or range(robot.n))
    why_missing = (
        f"were not run (--joints {args.joints})"
        if args.joints
        else "were not run (default on the Atlas arm: the hydraulic joints, as Fig. 4 of the paper)"
    )
    say(
        args,
        f"simulating constant-velocity runs of joints {[j + 1 for j in joints]} on the {args.scenario} plant ...",
    )
    exp = run_friction_experiments(
        robot,
        joints=joints,
        speeds=parse_floats(args.speeds, "--speeds"),
        offset=not args.no_offset,
        model=perturb_model(robot, args.model_error, seed=args.seed),
        seed=args.seed,
        extra_joint_torque=scenario_extra(robot, args.scenario),
        n_jobs=args.jobs,
        progress=not args.quiet,
    )
    return list(exp.fits), exp.friction, (exp.truth.coulomb, exp.truth.viscous), why_missing


def _friction_rows(
    robot: Any, fits: list[FrictionFit], truth: tuple[np.ndarray, np.ndarray] | None
) -> list[dict[str, object]]:
    """One row per fitted joint for friction.csv and the table, with the errors against ``truth`` if known."""
    rows = []
    for ft in fits:
        row: dict[str, object] = {
            "joint": f"{ft.joint + 1} ({robot.joint_names[ft.joint]})",
            "mu_C": ft.coulomb,
            "mu_C_std": ft.coulomb_std,
            "d_v": ft.viscous,
            "d_v_std": ft.viscous_std,
            "offset": ft.offset,
            "points": len(ft.points),
        }
        if truth is not None:
            mu, dv = truth[0][ft.joint], truth[1][ft.joint]
            row["mu_C_true"] = float(mu)
            row["mu_C_err_pct"] = 100 * (ft.coulomb - mu) / mu if mu else None
            row["d_v_true"] = float(dv)
            row["d_v_err_pct"] = 100 * (ft.viscous - dv) / dv if dv else None
        rows.append(row)
    return rows


def _write_friction(
    out: Path,
    robot: Any,
    fits: list[FrictionFit],
    friction: Any,
    rows: list[dict[str, object]],
    truth: tuple[np.ndarray, np.ndarray] | None,
    why_missing: str,
) -> None:
    """friction.csv, friction_points.csv, friction.json and Fig. 4 into ``out``; the table printed."""
    from reflexarm.ident.plots import plot_friction

    write_csv(out / "friction.csv", rows)
    points: list[dict[str, object]] = [
        {"joint": p.joint + 1, "velocity": p.velocity, "torque": p.torque, "torque_std": p.torque_std, "n": p.n_samples}
        for ft in fits
        for p in ft.points
    ]
    write_csv(out / "friction_points.csv", points)
    doc = friction_file(robot, friction, rows, why_missing)
    write_json(out / "friction.json", doc)
    fig = plot_friction(fits, out / "fig4_friction.png", joint_names=robot.joint_names, truth=truth)
    cols = [
        ("joint", "joint", "{}"),
        ("mu_C", "mu_C [Nm]", "{:.3f}"),
        ("d_v", "d_v [Nms/rad]", "{:.3f}"),
        ("offset", "offset [Nm]", "{:.3f}"),
        ("points", "points", "{}"),
    ]
    if truth is not None:
        cols[3:3] = [("mu_C_err_pct", "mu_C err [%]", "{:+.2f}"), ("d_v_err_pct", "d_v err [%]", "{:+.2f}")]
    print(format_table(rows, cols))
    if "not_identified" in doc:
        print(f"\nfriction.json: {doc['not_identified']['note']}")  # type: ignore[index]
    print(f"\nwrote {out}/ (friction.json, friction.csv, friction_points.csv, {fig.name})")
