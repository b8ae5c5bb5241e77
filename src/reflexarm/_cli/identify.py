"""``reflexarm excite``, ``reflexarm identify friction|dynamics`` and ``reflexarm validate`` (Sec. II-D).

Each works on the built-in Atlas arm (simulated experiments on the MuJoCo plant with the impedance
controller) or on a user's robot file and logs (``--robot``, ``--log``; log schema in
:mod:`reflexarm.ident.logs`). Results go to ``--out``: JSON/CSV tables and PNG figures.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm._cli.common import add_common, format_table, out_dir
from reflexarm.errors import ConfigError

DEFAULT_ROBOT = "atlas_v5_left_arm"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``excite``, ``identify`` (``friction``, ``dynamics``) and ``validate``."""
    e = sub.add_parser(
        "excite", help="optimize a Fourier excitation trajectory (condition number of the base regressor)"
    )
    _robot_args(e)
    e.add_argument("--base-frequency", type=float, default=0.1, help="base frequency f_f [Hz] (default 0.1)")
    e.add_argument("--harmonics", type=int, default=5, help="number of harmonics L (default 5)")
    e.add_argument(
        "--max-velocity", type=float, default=None, help="|dq| bound [rad/s] (default min(robot limit, 1.5))"
    )
    e.add_argument("--max-acceleration", type=float, default=5.0, help="|ddq| bound [rad/s^2] (default 5)")
    e.add_argument("--margin", type=float, default=0.1, help="distance from the joint limits [rad] (default 0.1)")
    e.add_argument("--maxiter", type=int, default=100, help="optimizer iterations (default 100)")
    add_common(e, default_out="results/excite")
    e.set_defaults(func=_excite)

    i = sub.add_parser("identify", help="identify friction (single-joint runs) or the base parameters")
    isub = i.add_subparsers(dest="what", metavar="WHAT")
    isub.required = True
    f = isub.add_parser(
        "friction",
        help="single-joint constant-velocity friction identification (Fig. 4, Table I): simulated on the "
        "plant, or from your logs",
    )
    _robot_args(f)
    f.add_argument(
        "--run",
        action="append",
        default=[],
        metavar="JOINT=LOG",
        help="a log of constant-velocity runs of joint JOINT (1-based); repeat per joint. Without --run the "
        "runs are simulated on the plant with the impedance controller",
    )
    f.add_argument(
        "--joints", default="1,2,3,4", help="joints to simulate, 1-based (default 1,2,3,4: the hydraulic ones)"
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
    add_common(f, default_out="results/friction")
    f.set_defaults(func=_identify_friction)

    d = isub.add_parser(
        "dynamics",
        help="base parameters by weighted least squares, combined and/or sequential; from your logs, or the "
        "full simulated study (friction runs, optimized excitation, validation) on the built-in arm",
    )
    _robot_args(d)
    d.add_argument("--log", action="append", default=[], help="identification log (.csv/.parquet/.npz); repeatable")
    d.add_argument("--validation-log", default=None, help="a different log to validate on")
    d.add_argument(
        "--split",
        type=float,
        default=None,
        help="identify on this first fraction of the (repaired) samples of --log, validate on the rest",
    )
    d.add_argument("--method", choices=("sequential", "combined", "both"), default="both")
    d.add_argument("--friction", default=None, help="friction.json from 'identify friction' (needed for sequential)")
    d.add_argument("--offset", action="store_true", help="estimate a constant torque offset per joint too")
    d.add_argument("--cutoff", type=float, default=10.0, help="low-pass cutoff for q, dq, ddq, tau [Hz] (default 10)")
    d.add_argument("--min-speed", type=float, default=0.0, help="leave out rows with |dq_j| below this [rad/s]")
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
    d.add_argument("--excitation", default=None, help="excitation.json from 'reflexarm excite' (simulation)")
    d.add_argument("--maxiter", type=int, default=100, help="excitation optimizer iterations (simulation)")
    d.add_argument("--jobs", type=int, default=1, help="single-joint runs in parallel (simulation)")
    add_common(d, default_out="results/identify")
    d.set_defaults(func=_identify_dynamics)

    v = sub.add_parser(
        "validate",
        help="validate an identified model on a log, or (--closed-loop) track a trajectory on the plant with "
        "the identified model against the perturbed nominal one",
    )
    _robot_args(v)
    v.add_argument("--model", required=True, help="model.json written by 'identify dynamics'")
    v.add_argument("--log", default=None, help="validation log (.csv/.parquet/.npz)")
    v.add_argument("--cutoff", type=float, default=10.0, help="low-pass cutoff for the states [Hz] (default 10)")
    v.add_argument("--closed-loop", action="store_true", help="compare tracking on the simulated plant")
    v.add_argument("--kappa-f", type=int, choices=(0, 1), default=1, help="friction compensation in (2) (closed loop)")
    v.add_argument("--duration", type=float, default=20.0, help="closed-loop run length [s] (default 20)")
    add_common(v, default_out="results/validate")
    v.set_defaults(func=_validate)


# ---------------------------------------------------------------------------------------------- helpers
def _robot_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", default=DEFAULT_ROBOT, help=f"built-in name or .urdf/.xml file (default {DEFAULT_ROBOT})")
    p.add_argument("--ee-frame", default=None, help="end-effector frame (user robot files)")


def _load_robot(args: argparse.Namespace) -> Any:
    from reflexarm.robots import load_robot

    return load_robot(args.robot, ee_frame=args.ee_frame)


def _write_csv(path: Path, rows: list[dict[str, object]]) -> Path:
    if not rows:
        return path
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    return path


def _json(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def _write_json(path: Path, obj: Any) -> Path:
    path.write_text(json.dumps(_json(obj), indent=1))
    return path


def _floats(text: str | None, what: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise ConfigError(f"{what} must be comma-separated numbers; got {text!r}") from e


def _joints(text: str, n: int) -> list[int]:
    try:
        js = [int(x) - 1 for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise ConfigError(f"--joints must be comma-separated 1-based joint numbers; got {text!r}") from e
    bad = [j + 1 for j in js if not 0 <= j < n]
    if bad:
        raise ConfigError(f"joint(s) {bad} out of range; the robot has joints 1..{n}")
    return js


def _say(args: argparse.Namespace, msg: str) -> None:
    if not args.quiet:
        print(msg, file=sys.stderr)


# ---------------------------------------------------------------------------------------------- excite
def _excite(args: argparse.Namespace) -> int:
    from reflexarm.ident import compute_base_parameters
    from reflexarm.ident.excitation import optimize_excitation
    from reflexarm.ident.plots import plot_excitation

    out = out_dir(args)
    robot = _load_robot(args)
    base = compute_base_parameters(robot)
    _say(args, f"{robot.name}: {base.n_base} base parameters of {base.n_standard}; optimizing ...")
    design = optimize_excitation(
        robot,
        base=base,
        base_frequency=2 * np.pi * args.base_frequency,
        n_harmonics=args.harmonics,
        max_velocity=args.max_velocity,
        max_acceleration=args.max_acceleration,
        position_margin=args.margin,
        maxiter=args.maxiter,
        seed=args.seed,
        progress=not args.quiet,
    )
    _write_json(
        out / "excitation.json",
        {"robot": robot.name, "n_base": base.n_base, "base_parameters": base.explain(), **design.to_dict()},
    )
    fig = plot_excitation(design, out / "excitation.png", joint_names=robot.joint_names)
    print(f"base parameters: {base.n_base} of {base.n_standard}")
    print(base.explain())
    print(
        f"condition number of the base regressor: {design.condition_initial:.4g} (start) -> "
        f"{design.condition_optimized:.4g} (optimized, {design.iterations} iterations)"
    )
    lim = design.limits_optimized
    print(
        f"limit use at 1 kHz (<= 1 is within): position {lim['position']:.3f}, velocity {lim['velocity']:.3f}, "
        f"acceleration {lim['acceleration']:.3f}"
    )
    print(f"\nwrote {out}/ (excitation.json, {fig.name})")
    return 0


# ---------------------------------------------------------------------------------------------- friction
def _identify_friction(args: argparse.Namespace) -> int:
    from reflexarm.ident import load_log
    from reflexarm.ident.joint_friction import (
        fit_friction,
        friction_from_fits,
        friction_points,
        segment_constant_velocity,
    )
    from reflexarm.ident.plots import plot_friction

    out = out_dir(args)
    robot = _load_robot(args)
    truth = None
    if args.run:
        fits = []
        for spec in args.run:
            if "=" not in spec:
                raise ConfigError(f"--run expects JOINT=LOG (e.g. 3=runs_j3.csv); got {spec!r}")
            js, path = spec.split("=", 1)
            j = _joints(js, robot.n)[0]
            log = load_log(path, n_joints=robot.n)
            from reflexarm.ident import preprocess_log

            proc = preprocess_log(log)
            intervals = segment_constant_velocity(proc.t, proc.dq[:, j], q=proc.q[:, j])
            if not intervals:
                raise ConfigError(f"{Path(path).name}: no constant-velocity interval of joint {j + 1} found")
            pts = friction_points(robot, j, proc.t, proc.q, proc.dq, proc.tau, intervals)
            fits.append(fit_friction(pts, offset=not args.no_offset))
        friction = friction_from_fits(fits, robot.n)
    else:
        from reflexarm.experiments.identification import _scenario_extra, run_friction_experiments
        from reflexarm.robots import perturb_model

        joints = _joints(args.joints, robot.n)
        _say(
            args,
            f"simulating constant-velocity runs of joints {[j + 1 for j in joints]} on the {args.scenario} plant ...",
        )
        exp = run_friction_experiments(
            robot,
            joints=joints,
            speeds=_floats(args.speeds, "--speeds"),
            offset=not args.no_offset,
            model=perturb_model(robot, args.model_error, seed=args.seed),
            seed=args.seed,
            extra_joint_torque=_scenario_extra(robot, args.scenario),
            n_jobs=args.jobs,
            progress=not args.quiet,
        )
        fits = list(exp.fits)
        friction = exp.friction
        truth = (exp.truth.coulomb, exp.truth.viscous)
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
    _write_csv(out / "friction.csv", rows)
    points: list[dict[str, object]] = [
        {"joint": p.joint + 1, "velocity": p.velocity, "torque": p.torque, "torque_std": p.torque_std, "n": p.n_samples}
        for ft in fits
        for p in ft.points
    ]
    _write_csv(out / "friction_points.csv", points)
    _write_json(
        out / "friction.json",
        {"robot": robot.name, "joint_names": robot.joint_names, **friction.to_dict(), "fits": rows},
    )
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
    print(f"\nwrote {out}/ (friction.json, friction.csv, friction_points.csv, {fig.name})")
    return 0


# ---------------------------------------------------------------------------------------------- dynamics
def _noise_variance(text: str) -> Any:
    if text == "estimate":
        return "estimate"
    if text == "none":
        return None
    return np.asarray(_floats(text, "--noise-variance"))


def _load_friction(path: str | None) -> Any:
    if path is None:
        return None
    from reflexarm.ident import FrictionParameters

    try:
        d = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ConfigError(f"cannot read friction file {path!r}: {e}") from e
    fr = FrictionParameters.from_dict(d)
    return FrictionParameters(fr.viscous, fr.coulomb, None)  # offsets of single-joint runs are pose-specific


def _for_controller(result: Any, robot: Any, nominal: Any, args: argparse.Namespace) -> Any:
    """The result to write for the controller: projected onto consistent parameters if M(q) is indefinite."""
    from reflexarm.ident import project_physically_consistent
    from reflexarm.ident.consistency import is_physically_consistent

    if getattr(args, "no_projection", False) or is_physically_consistent(result, robot):
        return result
    projected = project_physically_consistent(result, nominal)
    print(
        f"{result.method}: M(q) of the least-squares estimate is not positive definite everywhere; "
        f"the model file holds the nearest consistent one ({projected.notes[-1]})"
    )
    return projected


def _identify_dynamics(args: argparse.Namespace) -> int:
    if not args.log:
        return _dynamics_study(args)
    from reflexarm.ident import (
        compute_base_parameters,
        identify_dynamics,
        load_log,
        preprocess_log,
        validate_model,
    )
    from reflexarm.ident.model_file import save_identified_model
    from reflexarm.ident.plots import plot_torque_validation

    out = out_dir(args)
    robot = _load_robot(args)
    base = compute_base_parameters(robot)
    print(f"{robot.name}: {base.n_base} base parameters of {base.n_standard}")
    logs = [load_log(p, n_joints=robot.n) for p in args.log]
    val_raw = None
    if args.split is not None:
        if len(logs) != 1:
            raise ConfigError("--split needs exactly one --log")
        full = preprocess_log(logs[0], cutoff_hz=args.cutoff)
        raw_ident, val_raw = logs[0].split(args.split)
        t_split = val_raw.t[0]
        ident = [full.select(full.t < t_split)]
        states = full
    else:
        ident = [preprocess_log(lg, cutoff_hz=args.cutoff) for lg in logs]
        states = None
    if args.validation_log is not None:
        val_raw = load_log(args.validation_log, n_joints=robot.n)
        states = preprocess_log(val_raw, cutoff_hz=args.cutoff)
    friction = _load_friction(args.friction)
    methods = ["combined", "sequential"] if args.method == "both" else [args.method]
    if "sequential" in methods and friction is None:
        if args.method == "sequential":
            raise ConfigError("--method sequential needs --friction friction.json (from 'reflexarm identify friction')")
        methods = ["combined"]
        _say(args, "no --friction given: only the combined method is run")
    results = {}
    for m in methods:
        results[m] = identify_dynamics(
            robot,
            ident,
            method=m,  # type: ignore[arg-type]
            friction=friction,
            offset=args.offset,
            base=base,
            noise_variance=_noise_variance(args.noise_variance),
            min_speed=args.min_speed,
            progress=not args.quiet,
        )
        save_identified_model(_for_controller(results[m], robot, robot, args), robot, out / f"model_{m}.json")
    summary: dict[str, Any] = {"robot": robot.name, "n_base": base.n_base, "methods": {}}
    for m, r in results.items():
        summary["methods"][m] = {
            "condition_number": r.condition_number,
            "residual_rms": r.residual_rms,
            "friction": r.friction.to_dict(),
            "notes": r.notes,
            "timings": r.timings,
        }
    if val_raw is not None:
        vals = {m: validate_model(r, robot, val_raw, states=states) for m, r in results.items()}
        rows = []
        for j in range(robot.n):
            row: dict[str, object] = {"joint": f"{j + 1} ({robot.joint_names[j]})"}
            for m, v in vals.items():
                row[f"rmse_{m}"] = float(v.rmse[j])
                row[f"nrmse_{m}"] = float(v.nrmse[j])
                row[f"mse_{m}"] = float(v.mse[j])
            rows.append(row)
        _write_csv(out / "validation.csv", rows)
        for m, v in vals.items():
            summary["methods"][m]["validation"] = {
                "rmse": v.rmse,
                "nrmse": v.nrmse,
                "pooled_rmse": v.pooled_rmse,
                "samples": int(v.t.size),
            }
        cols = [("joint", "joint", "{}")]
        for m in vals:
            cols += [(f"rmse_{m}", f"RMSE {m} [Nm]", "{:.3f}"), (f"nrmse_{m}", f"RMSE/std {m}", "{:.3f}")]
        print(format_table(rows, cols))
        for m, v in vals.items():
            print(f"pooled validation RMSE ({m}): {v.pooled_rmse:.4f} Nm over {v.t.size:,} samples")
        plot_torque_validation(vals, out / "fig6_torques.png", joint_names=robot.joint_names)
    _write_json(out / "identification.json", summary)
    print(
        f"\nwrote {out}/ ({', '.join(f'model_{m}.json' for m in results)}, identification.json"
        + (", validation.csv, fig6_torques.png)" if val_raw is not None else ")")
    )
    return 0


def _dynamics_study(args: argparse.Namespace) -> int:
    from reflexarm.experiments.identification import MOVING_SPEED, run_identification_study
    from reflexarm.ident.excitation import ExcitationDesign, FourierTrajectory, optimize_excitation
    from reflexarm.ident.model_file import save_identified_model
    from reflexarm.ident.plots import plot_excitation, plot_friction, plot_torque_validation

    out = out_dir(args)
    robot = _load_robot(args)
    excitation = None
    if args.excitation is not None:
        d = json.loads(Path(args.excitation).read_text())
        tr = FourierTrajectory.from_dict(d["trajectory"])
        excitation = optimize_excitation(
            robot, initial=tr, base_frequency=tr.base_frequency, n_harmonics=tr.n_harmonics, maxiter=0
        )
        excitation = ExcitationDesign(
            tr,
            excitation.initial,
            d["condition_initial"],
            d["condition_optimized"],
            d["limits_initial"],
            d["limits_optimized"],
            d["iterations"],
            d["message"],
            d.get("bounds", {}),
        )
    _say(
        args,
        f"simulated study on the {args.scenario} plant: single-joint friction runs, excitation run, "
        "validation run (a few minutes) ...",
    )
    st = run_identification_study(
        robot,
        scenario=args.scenario,
        excitation=excitation,
        seed=args.seed,
        maxiter=args.maxiter,
        n_jobs=args.jobs,
        progress=not args.quiet,
    )
    base = st.results["sequential"].base
    print(f"{robot.name}: {base.n_base} base parameters of {base.n_standard}")
    print(
        f"excitation: condition number {st.excitation.condition_initial:.4g} -> {st.excitation.condition_optimized:.4g}"
    )
    for variant, moving in (("all samples", False), ("moving rows only", True)):
        rows = st.table(moving=moving)
        name = "table1_mse" + ("_moving_rows" if moving else "")
        _write_csv(out / f"{name}.csv", rows)
        print(
            f"\nTable I analogue, identified from {variant} (scenario {args.scenario}); validation MSE [Nm^2] "
            f"over all samples and over samples with |dq_j| >= {MOVING_SPEED:g} rad/s:"
        )
        print(
            format_table(
                rows,
                [
                    ("joint", "joint", "{}"),
                    ("mse_combined", "MSE comb", "{:.3f}"),
                    ("mse_sequential", "MSE seq", "{:.3f}"),
                    ("mse_moving_combined", "MSE comb moving", "{:.3f}"),
                    ("mse_moving_sequential", "MSE seq moving", "{:.3f}"),
                    ("mu_C_single_joint", "mu_C,p", "{:.2f}"),
                    ("d_v_single_joint", "d_v,p", "{:.2f}"),
                    ("mu_C_combined", "mu_C comb", "{:.2f}"),
                    ("d_v_combined", "d_v comb", "{:.2f}"),
                    ("mu_C_true", "mu_C true", "{:.2f}"),
                    ("d_v_true", "d_v true", "{:.2f}"),
                ],
            )
        )
        h = st.hydraulic_mse(moving=moving)
        print("hydraulic joints, mean MSE: " + ", ".join(f"{k} {v:.3f}" for k, v in h.items()))
    rel = {
        m: float(np.linalg.norm(r.beta_b - st.true_base) / np.linalg.norm(st.true_base)) for m, r in st.results.items()
    }
    from reflexarm.experiments.identification import NOMINAL_ERROR_LEVEL
    from reflexarm.robots import perturb_model

    nominal = perturb_model(robot, NOMINAL_ERROR_LEVEL, seed=args.seed)  # the model the study's user starts from
    for m, r in st.results_moving.items():
        save_identified_model(
            _for_controller(r, robot, nominal, args),
            robot,
            out / f"model_{m}.json",
            extra={"scenario": args.scenario, "min_speed": MOVING_SPEED},
        )
    _write_json(
        out / "study.json",
        {
            "robot": robot.name,
            "scenario": args.scenario,
            "notes": st.notes,
            "n_base": base.n_base,
            "condition_initial": st.excitation.condition_initial,
            "condition_optimized": st.excitation.condition_optimized,
            "hydraulic_mse": st.hydraulic_mse(),
            "hydraulic_mse_moving_rows": st.hydraulic_mse(moving=True),
            "base_relative_error": rel,
            "friction_fits": st.friction.table(robot.joint_names),
            "table": st.table(),
            "table_moving_rows": st.table(moving=True),
        },
    )
    plot_friction(
        list(st.friction.fits),
        out / "fig4_friction.png",
        joint_names=robot.joint_names,
        truth=(st.friction.truth.coulomb, st.friction.truth.viscous),
    )
    t0 = st.validation_log.t[0]
    plot_torque_validation(
        st.validations,
        out / "fig6_torques.png",
        joint_names=robot.joint_names,
        window=(t0, t0 + st.validation_trajectory.period),
    )
    plot_excitation(st.excitation, out / "excitation.png", joint_names=robot.joint_names)
    print("\nrelative error of the base parameters: " + ", ".join(f"{m} {v:.3f}" for m, v in rel.items()))
    print(
        f"\nwrote {out}/ (model_combined.json, model_sequential.json, study.json, table1_mse*.csv, "
        "fig4_friction.png, fig6_torques.png, excitation.png)"
    )
    return 0


# ---------------------------------------------------------------------------------------------- validate
def _validate(args: argparse.Namespace) -> int:
    from reflexarm.ident import load_log, preprocess_log, validate_model
    from reflexarm.ident.model_file import load_identified_model, read_identified_model
    from reflexarm.ident.plots import plot_torque_validation

    out = out_dir(args)
    robot = _load_robot(args)
    result, _ = read_identified_model(args.model)
    identified = load_identified_model(args.model, robot)
    if args.log is None and not args.closed_loop:
        raise ConfigError("give --log FILE to validate on, or --closed-loop to compare tracking in simulation")
    summary: dict[str, Any] = {"model": str(args.model), "robot": robot.name}
    if args.log is not None:
        raw = load_log(args.log, n_joints=robot.n)
        states = preprocess_log(raw, cutoff_hz=args.cutoff)
        v = validate_model(result, robot, raw, states=states, label=result.method)
        rows = v.table(robot.joint_names)
        _write_csv(out / "validation.csv", rows)
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
        print(f"pooled RMSE: {v.pooled_rmse:.4f} Nm over {v.t.size:,} samples")
        summary["validation"] = {"rows": rows, "pooled_rmse": v.pooled_rmse}
        plot_torque_validation({result.method: v}, out / "fig6_torques.png", joint_names=robot.joint_names)
    if args.closed_loop:
        from reflexarm.experiments.identification import NOMINAL_ERROR_LEVEL, compare_tracking
        from reflexarm.ident.excitation import optimize_excitation
        from reflexarm.robots import perturb_model

        nominal = perturb_model(robot, NOMINAL_ERROR_LEVEL, seed=args.seed)
        traj = optimize_excitation(robot, maxiter=0, seed=args.seed + 7).initial
        _say(args, f"tracking a {args.duration:g} s trajectory with the perturbed nominal and the identified model ...")
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
        _write_csv(out / "tracking.csv", rows)
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
    _write_json(out / "validate.json", summary)
    print(f"\nwrote {out}/")
    return 0
