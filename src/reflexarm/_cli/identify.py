"""``reflexarm excite``, ``reflexarm identify friction|dynamics`` and ``reflexarm validate`` (Sec. II-D).

This module registers the commands and runs ``excite``; ``identify friction`` is in
:mod:`reflexarm._cli.identify_friction`, ``identify dynamics`` and ``validate`` are in
:mod:`reflexarm._cli.identify_dynamics`.

Each works on the built-in Atlas arm (simulated experiments on the MuJoCo plant with the impedance
controller) or on a user's robot file and logs (``--robot``, ``--log``; log schema in
:mod:`reflexarm.logs`). Results go to ``--out``: JSON/CSV tables and PNG figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm._cli.common import add_common, out_dir
from reflexarm._cli.ident_common import export_excitation_csv, load_robot_arg, robot_args, say, write_json
from reflexarm._cli.identify_dynamics import identify_dynamics_command, validate_command
from reflexarm._cli.identify_friction import identify_friction_command
from reflexarm._cli.identify_payload import add_friction_from_motion_options, register_payload
from reflexarm._cli.log_options import add_log_options
from reflexarm.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``excite``, ``identify`` (``friction``, ``dynamics``) and ``validate``."""
    _register_excite(sub)
    i = sub.add_parser("identify", help="identify friction (single-joint runs) or the base parameters")
    isub = i.add_subparsers(dest="what", metavar="WHAT")
    isub.required = True
    _register_friction(isub)
    _register_dynamics(isub)
    register_payload(isub)
    _register_validate(sub)


def _register_excite(sub: argparse._SubParsersAction) -> None:
    """``excite``: the trajectory's bounds and optimizer, then what else to write (--record, --csv)."""
    e = sub.add_parser(
        "excite", help="optimize a Fourier excitation trajectory (condition number of the base regressor)"
    )
    robot_args(e)
    e.add_argument("--base-frequency", type=float, default=0.1, help="base frequency f_f [Hz] (default 0.1)")
    e.add_argument("--harmonics", type=int, default=5, help="number of harmonics L (default 5)")
    e.add_argument(
        "--max-velocity", type=float, default=None, help="|dq| bound [rad/s] (default min(robot limit, 1.5))"
    )
    e.add_argument("--max-acceleration", type=float, default=5.0, help="|ddq| bound [rad/s^2] (default 5)")
    e.add_argument("--margin", type=float, default=0.1, help="distance from the joint limits [rad] (default 0.1)")
    e.add_argument("--maxiter", type=int, default=100, help="optimizer iterations (default 100)")
    e.add_argument(
        "--torque-fraction",
        type=float,
        default=0.8,
        help="the model's joint torques (inverse dynamics + friction along the trajectory) stay within this share "
        "of the robot file's effort limits (default 0.8: room for the controller's feedback and the model's error)",
    )
    e.add_argument(
        "--floor",
        default="default",
        metavar="Z",
        help="height [m] in the base frame of a floor or table no point of the arm may go below (2 cm clearance); "
        "'none': no workspace bound (default: the base plane z = 0 when the arm stands on it)",
    )
    e.add_argument(
        "--no-self-collision",
        action="store_true",
        help="do not keep the links apart (default: capsules fitted to the file's collision geometry, 2 cm apart)",
    )
    add_common(e, default_out="results/excite")
    e.add_argument(
        "--record",
        default=None,
        metavar="LOG",
        help="also run the trajectory on the simulated plant (impedance controller on the +-10 %% perturbed model, "
        "the paper's sensor noise with seed --seed) and write what the robot logs to LOG (.csv/.parquet/.npz); "
        "with --maxiter 0 the trajectory is the seeded random start: e.g. a held-out validation log",
    )
    e.add_argument(
        "--periods", type=int, default=2, help="periods recorded with --record and exported with --csv (default 2)"
    )
    e.add_argument(
        "--csv",
        default=None,
        metavar="OUT",
        help="also write the excitation sampled at --rate as CSV (t, position_<joint>, velocity_<joint>, "
        "acceleration_<joint> in s, rad, rad/s, rad/s^2), checked against the position, velocity and acceleration "
        "limits (refused beyond them)",
    )
    e.add_argument("--rate", type=float, default=1000.0, help="sampling rate of --csv [Hz] (default 1000)")
    e.set_defaults(func=_excite)


def _register_friction(isub: argparse._SubParsersAction) -> None:
    """``identify friction``: logged runs (--run) or the simulated ones, the fit, from-motion and log options."""
    f = isub.add_parser(
        "friction",
        help="single-joint constant-velocity friction identification (Fig. 4, Table I): simulated on the "
        "plant, or from your logs",
    )
    robot_args(f)
    f.add_argument(
        "--run",
        action="append",
        default=[],
        metavar="JOINT=LOG",
        help="a log of constant-velocity runs of joint JOINT (1-based); repeat per joint. Without --run the "
        "runs are simulated on the plant with the impedance controller",
    )
    f.add_argument(
        "--joints",
        default=None,
        help="joints to simulate, 1-based, comma-separated (default: the hydraulic joints 1-4 on the Atlas arm, "
        "every joint on other arms); friction.json has null (not identified) for the others, which 'identify "
        "dynamics --friction' estimates",
    )
    f.add_argument("--speeds", default=None, help="comma-separated speeds [rad/s] (default 0.1,0.2,0.35,0.5,0.75,1)")
    f.add_argument("--scenario", choices=("table1", "stribeck"), default="table1", help="plant friction (simulation)")
    f.add_argument("--no-offset", action="store_true", help="fit Coulomb + viscous only (no offset)")
    f.add_argument(
        "--model-error",
        type=float,
        default=0.1,
        help="simulation: the controller's (and the rigid-body removal's) model has uniform errors of this "
        "level (default 0.1: +-10 %%, the paper's)",
    )
    f.add_argument("--jobs", type=int, default=1, help="joints simulated in parallel (default 1)")
    add_friction_from_motion_options(f)
    add_log_options(f)
    add_common(f, default_out="results/friction")
    f.set_defaults(func=identify_friction_command)


def _register_dynamics(isub: argparse._SubParsersAction) -> None:
    """``identify dynamics``: the logs, the estimator's options, then the simulated study's."""
    d = isub.add_parser(
        "dynamics",
        help="base parameters by weighted least squares, combined and/or sequential; from your logs, or the "
        "full simulated study (friction runs, optimized excitation, validation) on the built-in arm",
    )
    robot_args(d)
    d.add_argument(
        "--log",
        action="append",
        default=[],
        help="identification log (.csv/.parquet/.npz, or a ROS 2 bag: .db3, .mcap or its folder); repeatable",
    )
    d.add_argument("--validation-log", default=None, help="a different log to validate on")
    d.add_argument(
        "--split",
        type=float,
        default=None,
        help="identify on this first fraction of the (repaired) samples of --log, validate on the rest (times are "
        "relative to the log's first sample)",
    )
    d.add_argument("--method", choices=("sequential", "combined", "both"), default="both")
    d.add_argument("--friction", default=None, help="friction.json from 'identify friction' (needed for sequential)")
    d.add_argument("--offset", action="store_true", help="estimate a constant torque offset per joint too")
    d.add_argument("--cutoff", type=float, default=10.0, help="low-pass cutoff for q, dq, ddq, tau [Hz] (default 10)")
    d.add_argument(
        "--block-rows",
        type=int,
        default=None,
        metavar="N",
        help="read CSV/Parquet logs in blocks of N rows: memory bounded by a block, not by the log, the same "
        "result to ~1e-10 (default: blocks of 100000 rows for logs over 100 MB; 0: read whole)",
    )
    d.add_argument(
        "--min-speed",
        type=float,
        default=None,
        help="leave out rows with |dq_j| below this [rad/s] (default: 0 for --log; the simulated study uses the "
        "paper's velocity noise level, 0.055, for both methods)",
    )
    d.add_argument(
        "--noise-variance", default="estimate", help="'estimate', 'none' or comma-separated sigma_j^2 [Nm^2]"
    )
    d.add_argument(
        "--no-projection",
        action="store_true",
        help="write the least-squares model even if M(q) is not positive definite (default: project it onto "
        "physically consistent parameters first)",
    )
    d.add_argument("--scenario", choices=("table1", "stribeck"), default="table1", help="plant friction (simulation)")
    d.add_argument(
        "--excitation",
        default=None,
        help="excitation.json from 'reflexarm excite' (simulation; optimized coefficients differ between "
        "machines, so pass one for runs that repeat elsewhere)",
    )
    d.add_argument("--maxiter", type=int, default=100, help="excitation optimizer iterations (simulation)")
    d.add_argument("--jobs", type=int, default=1, help="single-joint runs in parallel (simulation)")
    d.add_argument(
        "--threads",
        type=int,
        default=1,
        help="BLAS threads of the identification (Gram products, QR, solves, projection; default 1: many threads "
        "lose badly when another process keeps a core busy); 0: as BLAS is configured",
    )
    add_log_options(d)
    add_common(d, default_out="results/identify")
    d.set_defaults(func=identify_dynamics_command)


def _register_validate(sub: argparse._SubParsersAction) -> None:
    """``validate``: the model and the log, or the closed-loop comparison on the plant."""
    v = sub.add_parser(
        "validate",
        help="validate an identified model on a log, or (--closed-loop) track a trajectory on the plant with "
        "the identified model against the perturbed nominal one",
    )
    robot_args(v)
    v.add_argument("--model", required=True, help="model.json written by 'identify dynamics'")
    v.add_argument("--log", default=None, help="validation log (.csv/.parquet/.npz or a ROS 2 bag)")
    v.add_argument("--cutoff", type=float, default=10.0, help="low-pass cutoff for the states [Hz] (default 10)")
    v.add_argument(
        "--block-rows",
        type=int,
        default=None,
        metavar="N",
        help="read a CSV/Parquet --log in blocks of N rows (memory bounded by a block; default: blocks of 100000 "
        "rows for logs over 100 MB; 0: read whole)",
    )
    v.add_argument(
        "--friction-model",
        choices=("controller", "identified"),
        default="controller",
        help="friction to score: 'controller' (default: as the controller loads the model, Coulomb smoothed over "
        "the model file's velocity band) or 'identified' (exact sign and offsets, the least-squares model)",
    )
    v.add_argument("--closed-loop", action="store_true", help="compare tracking on the simulated plant")
    v.add_argument("--kappa-f", type=int, choices=(0, 1), default=1, help="friction compensation in (2) (closed loop)")
    v.add_argument("--duration", type=float, default=20.0, help="closed-loop run length [s] (default 20)")
    add_log_options(v)
    add_common(v, default_out="results/validate")
    v.set_defaults(func=validate_command)


# ---------------------------------------------------------------------------------------------- excite
def _excite(args: argparse.Namespace) -> int:
    from reflexarm.ident import compute_base_parameters
    from reflexarm.ident.excitation.design import optimize_excitation
    from reflexarm.ident.plots import plot_excitation

    out = out_dir(args)
    robot = load_robot_arg(args)
    base = compute_base_parameters(robot)
    say(args, f"{robot.name}: {base.n_base} base parameters of {base.n_standard}; optimizing ...")
    design = optimize_excitation(
        robot,
        base=base,
        base_frequency=2 * np.pi * args.base_frequency,
        n_harmonics=args.harmonics,
        max_velocity=args.max_velocity,
        max_acceleration=args.max_acceleration,
        position_margin=args.margin,
        torque_fraction=args.torque_fraction,
        floor=_floor_arg(args.floor),
        self_collision=not args.no_self_collision,
        maxiter=args.maxiter,
        seed=args.seed,
        progress=not args.quiet,
    )
    write_json(
        out / "excitation.json",
        {"robot": robot.name, "n_base": base.n_base, "base_parameters": base.explain(), **design.to_dict()},
    )
    fig = plot_excitation(design, out / "excitation.png", joint_names=robot.joint_names)
    tr = design.trajectory
    print(
        f"excitation: base frequency {tr.base_frequency_hz:g} Hz (period {tr.period:g} s), {tr.n_harmonics} harmonics "
        f"up to {tr.n_harmonics * tr.base_frequency_hz:g} Hz; excitation.json stores base_frequency_hz"
    )
    print(f"base parameters: {base.n_base} of {base.n_standard}")
    print(base.explain())
    print(
        f"condition number of the base regressor: {design.condition_initial:.4g} (start) -> "
        f"{design.condition_optimized:.4g} (optimized, {design.iterations} iterations)"
    )
    if design.diagnosis:
        print(f"WARNING: {design.diagnosis}")
    _print_limits(design)
    recorded = ""
    if args.csv is not None:
        recorded += ", " + export_excitation_csv(args, robot, design).name
    if args.record is not None:
        recorded += ", " + _record(args, robot, design.trajectory.with_periods(args.periods)).name
    print(f"\nwrote {out}/ (excitation.json, {fig.name}{recorded})")
    return 0


def _floor_arg(value: str) -> float | None | str:
    if value in ("default", "none"):
        return None if value == "none" else "default"
    try:
        return float(value)
    except ValueError:
        raise ConfigError(f"--floor expects a height in metres, 'none' or 'default'; got {value!r}") from None


def _print_limits(design: Any) -> None:
    """The bounds the excitation respects and how close it comes to each (1 kHz)."""
    lim = design.limits_optimized
    print(
        f"limit use at 1 kHz (<= 1 is within): position {lim['position']:.3f}, velocity {lim['velocity']:.3f}, "
        f"acceleration {lim['acceleration']:.3f}" + (f", torque {lim['torque']:.3f}" if "torque" in lim else "")
    )
    for note in design.limits.notes if design.limits is not None else ():
        print(f"  {note}")
    rep = design.limit_report
    if "torque" in rep:
        r = rep["torque"]
        print(
            f"  largest torque: joint {r['joint'] + 1} {r['value']:.4g} Nm at t = {r['time']:.4g} s "
            f"(bound {r['limit']:.4g})"
        )
    if "workspace" in rep:
        r = rep["workspace"]
        print(
            f"  lowest point: {r['clearance_m']:.3f} m above the floor (link of joint {r['joint'] + 1}, "
            f"t = {r['time']:.4g} s)"
        )
    if "self_collision" in rep:
        r = rep["self_collision"]
        i, j = r["pair"]
        print(f"  closest links: joints {i + 1} and {j + 1}, {r['clearance_m']:.3f} m apart (t = {r['time']:.4g} s)")


def _record(args: argparse.Namespace, robot: object, trajectory: object) -> Path:
    """Run ``trajectory`` on the plant as the simulated study does and write the log to ``--record``."""
    from reflexarm.experiments.identification import NOMINAL_ERROR_LEVEL, simulate_log
    from reflexarm.ident import save_log
    from reflexarm.robots import perturb_model

    nominal = perturb_model(robot, NOMINAL_ERROR_LEVEL, seed=args.seed)  # type: ignore[arg-type]
    duration = trajectory.duration  # type: ignore[attr-defined]
    say(args, f"recording {duration:g} s on the plant (paper noise, seed {args.seed}) ...")
    log, _ = simulate_log(
        robot,  # type: ignore[arg-type]
        trajectory,
        duration,
        controller_model=nominal,
        seed=args.seed,
        source=Path(args.record).stem,
        progress=not args.quiet,
    )
    path = save_log(log, args.record)
    print(f"recorded {len(log):,} samples ({duration:g} s) on the plant: {path}")
    from reflexarm.experiments.identification import describe_tracking

    for line in describe_tracking(robot, trajectory, log):  # type: ignore[arg-type]
        print(line)
    return path
