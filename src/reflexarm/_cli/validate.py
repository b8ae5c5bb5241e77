"""``reflexarm validate``: score a saved model on a log (read in blocks when it is long, :mod:`._cli.log_blocks`),
or track a trajectory with it on the simulated plant."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm._cli.common import format_table, out_dir
from reflexarm._cli.ident_common import load_robot_arg, say, write_csv, write_json
from reflexarm._cli.log_blocks import scan_logs
from reflexarm._cli.log_options import load_log_from_args
from reflexarm.errors import ConfigError


def _validate_log(args: argparse.Namespace, result: Any, robot: Any, identified: Any) -> Any:
    """The validation on ``--log``: in blocks (:func:`~reflexarm._cli.log_blocks.scan_logs`) when it can, else whole."""
    from reflexarm.ident import preprocess_log, validate_model
    from reflexarm.logs.blocks import NotStreamable

    # scored as the controller uses it (its friction: the model file's velocity band, issue 9 F6)
    scored = identified.friction if args.friction_model == "controller" else None
    tables = scan_logs(args, [args.log], robot)
    if tables is not None:
        from reflexarm.ident.estimation.streamed_validation import validate_streamed

        try:
            print(f"reading {tables[0].source} in blocks of {args.block_rows:,} rows ...")
            return validate_streamed(
                result, robot, tables[0], cutoff_hz=args.cutoff, block_rows=args.block_rows, label=result.method,
                friction=scored,
            )  # fmt: skip
        except NotStreamable as e:
            print(f"log: {e}; read whole")
    raw = load_log_from_args(args, args.log, robot)
    states = preprocess_log(raw, cutoff_hz=args.cutoff)
    return validate_model(result, robot, raw, states=states, label=result.method, friction=scored)


def validate_command(args: argparse.Namespace) -> int:
    """Score a saved model on ``--log``; ``--closed-loop``: tracking on the plant against the nominal model."""
    from reflexarm._cli.robot_options import DEFAULT_ROBOT
    from reflexarm.ident.export.model_file import load_identified_model, load_model_robot, read_identified_model
    from reflexarm.ident.plots import plot_torque_validation

    out = out_dir(args)
    result, doc = read_identified_model(args.model)
    robot = load_robot_arg(args)
    if args.robot == DEFAULT_ROBOT and doc.get("robot", {}).get("name") != robot.name:
        robot = load_model_robot(args.model)  # no --robot: the robot the model file names
        say(args, f"robot {robot.name!r} from {Path(args.model).name} (give --robot to use another file)")
    identified = load_identified_model(args.model, robot)
    if args.log is None and not args.closed_loop:
        raise ConfigError("give --log FILE to validate on, or --closed-loop to compare tracking in simulation")
    summary: dict[str, Any] = {"model": str(args.model), "robot": robot.name}
    if args.log is not None:
        v = _validate_log(args, result, robot, identified)
        print(f"friction {v.friction_model}")
        rows = v.table(robot.joint_names)
        write_csv(out / "validation.csv", rows)
        print(
            format_table(
                rows,
                [
                    ("joint", "joint", "{}"),
                    ("rmse", "RMSE [Nm]", "{:.4f}"),
                    ("nrmse", "RMSE/std", "{:.3f}"),
                    ("mse", "MSE [Nm^2]", "{:.4f}"),
                    ("torque_std", "std(tau) [Nm]", "{:.3f}"),
                ],
            )
        )
        samples = getattr(v, "samples", None) or v.t.size
        print(f"pooled RMSE: {v.pooled_rmse:.4f} Nm over {samples:,} samples; mean MSE over the joints: "
              f"{float(np.mean(v.mse)):.4f} Nm^2")  # fmt: skip
        summary["validation"] = {"rows": rows, "pooled_rmse": v.pooled_rmse, "mean_mse": float(np.mean(v.mse)),
                                 "friction_model": v.friction_model}  # fmt: skip
        plotted = getattr(v, "plotted", v)  # a log read in blocks: every k-th sample
        plot_torque_validation({result.method: plotted}, out / "fig6_torques.png", joint_names=robot.joint_names)
    if args.closed_loop:
        from reflexarm.experiments.identification import NOMINAL_ERROR_LEVEL, compare_tracking
        from reflexarm.ident.excitation.design import optimize_excitation
        from reflexarm.robots import perturb_model

        nominal = perturb_model(robot, NOMINAL_ERROR_LEVEL, seed=args.seed)
        traj = optimize_excitation(robot, maxiter=0, seed=args.seed + 7).initial
        say(args, f"tracking a {args.duration:g} s trajectory with the perturbed nominal and the identified model ...")
        cmp = compare_tracking(
            robot,
            {"perturbed nominal": nominal, "identified": identified},
            traj,
            args.duration,
            kappa_f=args.kappa_f,
            seed=args.seed,
            progress=not args.quiet,
        )
        rows = cmp.table(robot.joint_names)
        write_csv(out / "tracking.csv", rows)
        cols = [("model", "controller model", "{}")] + [
            (f"rms_{j + 1}", f"q{j + 1} [mrad]", "{:.2f}") for j in range(robot.n)
        ]
        print(
            format_table(
                [{k: (float(v) * 1e3 if k.startswith("rms") else v) for k, v in r.items()} for r in rows],  # type: ignore[arg-type]
                cols + [("rms_all", "all [mrad]", "{:.2f}")],
            )
        )
        summary["tracking_rms_rad"] = rows
    write_json(out / "validate.json", summary)
    print(f"\nwrote {out}/")
    return 0
