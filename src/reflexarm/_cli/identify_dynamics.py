"""``reflexarm identify dynamics`` and ``reflexarm validate`` (Sec. II-D 1 and 3, Table I, Fig. 6).

``identify dynamics`` identifies the base parameters from a user's logs, or (no ``--log``) runs the
simulated study on the built-in arm (:func:`reflexarm.experiments.identification.run_identification_study`):
the printed Table I, ``fig6_torques.png`` and the saved ``model_<method>.json`` are the same models.
``validate`` scores a saved model on a log, or tracks a trajectory with it on the plant.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm._cli.common import format_table, out_dir
from reflexarm._cli.ident_common import (
    for_controller,
    load_friction,
    load_robot_arg,
    parse_floats,
    say,
    write_csv,
    write_json,
    write_robot_copy,
)
from reflexarm._cli.log_blocks import scan_logs
from reflexarm._cli.log_options import load_log_from_args
from reflexarm._cli.validate import validate_command  # noqa: F401  (registered from here)
from reflexarm.errors import ConfigError

#: Columns of the printed Table I analogue.
TABLE_COLUMNS = [
    ("joint", "joint", "{}"),
    ("mse_combined", "MSE comb", "{:.3f}"),
    ("mse_sequential", "MSE seq", "{:.3f}"),
    ("mse_moving_combined", "MSE comb moving", "{:.3f}"),
    ("mse_moving_sequential", "MSE seq moving", "{:.3f}"),
    ("paper_mse_combined", "paper comb", "{:.2f}"),
    ("paper_mse_sequential", "paper seq", "{:.2f}"),
    ("mu_C_single_joint", "mu_C,p", "{:.2f}"),
    ("d_v_single_joint", "d_v,p", "{:.2f}"),
    ("mu_C_combined", "mu_C comb", "{:.2f}"),
    ("d_v_combined", "d_v comb", "{:.2f}"),
    ("mu_C_true", "mu_C true", "{:.2f}"),
    ("d_v_true", "d_v true", "{:.2f}"),
]


def _noise_variance(text: str) -> Any:
    if text == "estimate":
        return "estimate"
    if text == "none":
        return None
    return np.asarray(parse_floats(text, "--noise-variance"))


def identify_dynamics_command(args: argparse.Namespace) -> int:
    """From ``--log`` files; without them, the simulated study (:func:`dynamics_study_command`).

    BLAS runs on ``--threads`` threads throughout (default 1; 0: as configured).
    """
    from reflexarm.ident._blas_threads import blas_threads

    threads = getattr(args, "threads", 1)
    with blas_threads(None if threads == 0 else threads):
        if not args.log:
            return dynamics_study_command(args)
        return _identify_from_logs(args)


def _identify_from_logs(args: argparse.Namespace) -> int:
    """``identify dynamics --log ...``: identify, project if needed, validate, then write."""
    from reflexarm.ident import compute_base_parameters

    out = out_dir(args)
    robot = load_robot_arg(args)
    base = compute_base_parameters(robot)
    print(f"{robot.name}: {base.n_base} base parameters of {base.n_standard}")
    if args.split is not None and getattr(args, "block_rows", None):
        print("--split: the log is read whole (its identification and validation parts come from one preprocessing)")
    tables = None if args.split is not None else scan_logs(args, args.log, robot)
    if tables is None:
        ident, val_raw, states = _load_logs(args, robot)
    else:
        ident, val_raw, states = [], None, None
        if args.validation_log is not None:
            val_raw, states = _load_validation_log(args, robot)
    friction = load_friction(args.friction, robot)
    methods, not_run = _methods(args, friction, robot, base.n_base)
    if tables is None:
        estimates = {m: _identify(args, robot, base, ident, m, friction) for m in methods}
    else:
        estimates = _identify_streamed(args, robot, base, tables, methods, friction)
    results = {}  # the models as saved: what the validation below scores
    for m, estimate in estimates.items():
        results[m] = for_controller(estimate, robot, robot, args)
        if estimate.inertia_determinacy is not None:
            print(f"{m}: {estimate.inertia_determinacy.describe()}")
        for note in estimate.notes:  # whether the wrist wrench entered the regression, and why
            if note.startswith("wrist wrench"):
                print(f"{m}: {note}")
    _write_results(args, out, robot, base.n_base, results, not_run, val_raw, states)
    return 0


def _load_logs(args: argparse.Namespace, robot: Any) -> tuple[list[Any], Any, Any]:
    """(the preprocessed identification logs, the raw validation log or None, its states or None), read whole."""
    from reflexarm.ident import preprocess_log

    logs = [load_log_from_args(args, p, robot) for p in args.log]
    val_raw = states = None
    if args.split is not None:
        if len(logs) != 1:
            raise ConfigError("--split needs exactly one --log")
        full = preprocess_log(logs[0], cutoff_hz=args.cutoff)
        _, val_raw = logs[0].split(args.split)
        ident = [full.select(full.t < val_raw.t[0])]
        states = full
    else:
        ident = [preprocess_log(lg, cutoff_hz=args.cutoff) for lg in logs]
    if args.validation_log is not None:
        val_raw, states = _load_validation_log(args, robot)
    return ident, val_raw, states


def _load_validation_log(args: argparse.Namespace, robot: Any) -> tuple[Any, Any]:
    from reflexarm.ident import preprocess_log

    val_raw = load_log_from_args(args, args.validation_log, robot)
    return val_raw, preprocess_log(val_raw, cutoff_hz=args.cutoff)


def _methods(args: argparse.Namespace, friction: Any, robot: Any, n_base: int) -> tuple[list[str], dict[str, str]]:
    """The methods to run, and those ``--method`` asked for that cannot run with the reason (said, and in the
    summary)."""
    not_run: dict[str, str] = {}
    methods = ["combined", "sequential"] if args.method == "both" else [args.method]
    if "sequential" in methods and friction is None:
        if args.method == "sequential":
            raise ConfigError("--method sequential needs --friction friction.json (from 'reflexarm identify friction')")
        methods = ["combined"]
        not_run["sequential"] = (
            "not run: it needs the friction identified first (--friction friction.json); from these logs: 'reflexarm "
            "identify friction --log LOG' (ordinary motion) or '--run JOINT=LOG' (constant-velocity runs)"
        )
        print(f"--method both: only the combined model is written; sequential {not_run['sequential']}")
    if "sequential" in methods and friction.missing:
        print(_partial_friction_line(args.friction, friction, robot, n_base))
    return methods, not_run


def _estimator_options(args: argparse.Namespace, base: Any, friction: Any) -> dict[str, Any]:
    return {
        "friction": friction,
        "offset": args.offset,
        "base": base,
        "noise_variance": _noise_variance(args.noise_variance),
        "min_speed": 0.0 if args.min_speed is None else args.min_speed,
    }


def _identify(args: argparse.Namespace, robot: Any, base: Any, ident: list[Any], method: str, friction: Any) -> Any:
    from reflexarm.ident import identify_dynamics

    return identify_dynamics(
        robot,
        ident,
        method=method,  # type: ignore[arg-type]
        progress=not args.quiet,
        threads=None,  # set for the whole command by --threads
        filter_cutoff_hz=args.cutoff,
        **_estimator_options(args, base, friction),
    )


def _identify_streamed(
    args: argparse.Namespace, robot: Any, base: Any, tables: list[Any], methods: list[str], friction: Any
) -> dict[str, Any]:
    from reflexarm.ident.estimation.streaming import identify_dynamics_streamed

    print(f"reading {', '.join(t.source for t in tables)} in blocks of {args.block_rows:,} rows ...")
    return identify_dynamics_streamed(
        robot,
        tables,
        methods,
        cutoff_hz=args.cutoff,
        block_rows=args.block_rows,
        threads=None,  # set for the whole command by --threads
        **_estimator_options(args, base, friction),
    )


def _write_results(
    args: argparse.Namespace,
    out: Path,
    robot: Any,
    n_base: int,
    results: dict[str, Any],
    not_run: dict[str, str],
    val_raw: Any,
    states: Any,
) -> None:
    """Validate (what can still fail on the logs runs before anything is written), then write the models, their
    robot copies, the validation table and plot, and identification.json."""
    from reflexarm.ident import validate_model
    from reflexarm.ident.export.model_file import save_identified_model

    vals = {} if val_raw is None else {m: validate_model(r, robot, val_raw, states=states) for m, r in results.items()}
    copies, copy_notes = [], {}
    for m, r in results.items():
        save_identified_model(r, robot, out / f"model_{m}.json")
        name, copy_notes[m] = write_robot_copy(r, robot, out, args)
        copies.append(name)
    summary: dict[str, Any] = {"robot": robot.name, "n_base": n_base, "methods": {}, "not_run": not_run}
    for (m, r), name in zip(results.items(), copies, strict=True):
        summary["methods"][m] = {
            "robot_copy": {"file": name, "notes": copy_notes[m]},
            "condition_number": r.condition_number,
            "residual_rms": r.residual_rms,
            "friction": r.friction.to_dict(),
            "friction_estimated_joints": [j + 1 for j in r.estimated_friction_joints],
            "inertia_determinacy": None if r.inertia_determinacy is None else r.inertia_determinacy.to_dict(),
            "notes": r.notes,
            "timings": r.timings,
        }
    if vals:
        _write_validation(out, robot, vals, summary)
    write_json(out / "identification.json", summary)
    print(
        f"\nwrote {out}/ ({', '.join([f'model_{m}.json' for m in results] + [c for c in copies if c])}, "
        "identification.json" + (", validation.csv, fig6_torques.png)" if vals else ")")
    )


def _write_validation(out: Path, robot: Any, vals: dict[str, Any], summary: dict[str, Any]) -> None:
    from reflexarm.ident.plots import plot_torque_validation

    rows = []
    for j in range(robot.n):
        row: dict[str, object] = {"joint": f"{j + 1} ({robot.joint_names[j]})"}
        for m, v in vals.items():
            row[f"rmse_{m}"] = float(v.rmse[j])
            row[f"nrmse_{m}"] = float(v.nrmse[j])
            row[f"mse_{m}"] = float(v.mse[j])
        rows.append(row)
    write_csv(out / "validation.csv", rows)
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


def _partial_friction_line(path: str, friction: Any, robot: Any, n_base: int) -> str:
    """What the sequential method does with a friction file that lacks some joints (they are estimated)."""
    from reflexarm.ident.friction.parameters import format_joints

    missing, known = friction.missing, friction.known
    line = (
        f"sequential: {Path(path).name} has no friction for joint(s) {format_joints(missing, robot.joint_names)} "
        f"(not identified): their d_v, mu_C are estimated with the base parameters ({n_base} + {2 * len(missing)} "
        f"unknowns); joint(s) {format_joints(known, robot.joint_names) or '(none)'} keep the file's friction (eq. 16)"
    )
    if not known:
        return line + ": the same unknowns as the combined method"
    return line + (
        f". For every joint's friction fixed ({n_base} unknowns), identify it: 'identify friction --joints "
        + ",".join(str(j + 1) for j in range(robot.n))
        + "'"
    )


def _load_excitation(robot: Any, path: str) -> Any:
    """An ExcitationDesign from an excitation.json of 'reflexarm excite' (no optimization)."""
    from reflexarm.ident.excitation.design import ExcitationDesign, FourierTrajectory, regressor_condition

    try:
        d = json.loads(Path(path).read_text())
        tr = FourierTrajectory.from_dict(d["trajectory"])
        initial = FourierTrajectory.from_dict(d["initial"]) if d.get("initial") is not None else None
    except (OSError, json.JSONDecodeError, KeyError) as e:
        raise ConfigError(f"cannot read excitation file {path!r} (from 'reflexarm excite'): {e}") from e
    cond = regressor_condition(robot, tr)
    limits = d.get("limits_optimized", {})
    if initial is None:  # a file without the optimizer's start: the trajectory stands for both
        return ExcitationDesign(tr, tr, cond, cond, limits, limits, 0, f"read from {path}", d.get("bounds", {}))
    return ExcitationDesign(
        tr,
        initial,
        regressor_condition(robot, initial),
        cond,
        d.get("limits_initial", {}),
        limits,
        int(d.get("iterations", 0)),
        f"read from {path}",
        d.get("bounds", {}),
    )


def dynamics_study_command(args: argparse.Namespace) -> int:
    """The simulated Table I study; prints, plots and saves the same (possibly projected) models."""
    from reflexarm.experiments.identification import MOVING_SPEED, run_identification_study

    out = out_dir(args)
    robot = load_robot_arg(args)
    excitation = None if args.excitation is None else _load_excitation(robot, args.excitation)
    min_speed = MOVING_SPEED if args.min_speed is None else args.min_speed
    say(
        args,
        f"simulated study on the {args.scenario} plant: single-joint friction runs, excitation run, "
        "validation run (a few minutes) ...",
    )
    st = run_identification_study(
        robot,
        scenario=args.scenario,
        excitation=excitation,
        min_speed=min_speed,
        project=not args.no_projection,
        seed=args.seed,
        maxiter=args.maxiter,
        n_jobs=args.jobs,
        progress=not args.quiet,
        threads=None,  # set for the whole command by --threads
    )
    base = st.results["sequential"].base
    print(f"{robot.name}: {base.n_base} base parameters of {base.n_standard}")
    rows, h = _print_study(args, out, robot, st, min_speed)
    _save_study(args, out, robot, st, rows, h)
    return 0


def _print_study(
    args: argparse.Namespace, out: Path, robot: Any, st: Any, min_speed: float
) -> tuple[list[Any], dict[str, Any]]:
    """The excitation's condition numbers, Table I, the mean MSEs and the methods compared (the table's rows and
    the compared MSEs are returned for the files)."""
    from reflexarm.experiments.identification import MOVING_SPEED, PAPER_TABLE1_MSE, compare_methods

    if args.excitation is None:
        print(
            f"excitation: condition number {st.excitation.condition_initial:.4g} -> "
            f"{st.excitation.condition_optimized:.4g} (optimized here; saved to excitation.json)"
        )
    else:
        print(f"excitation: {args.excitation}, condition number {st.excitation.condition_optimized:.4g}")
    rows = st.table()
    write_csv(out / "table1_mse.csv", rows)
    print(
        f"\nTable I analogue (scenario {args.scenario}). Both methods identified from the same rows: every "
        f"excitation sample except, per joint, those with |dq_j| < {min_speed:g} rad/s. Validation on a "
        f"different trajectory with its own noise seed; MSE [Nm^2] of the saved model files over all samples "
        f"and over the samples with |dq_j| >= {MOVING_SPEED:g} rad/s:"
    )
    print(format_table(rows, TABLE_COLUMNS))
    groups = [(st.compared_label(), st.compared_joints)] if st.is_paper_arm else []
    for what, joints in groups + [(f"all {robot.n} joints", None)]:
        mean = st.mean_mse(joints)
        print(f"mean MSE, {what}: " + ", ".join(f"{k} {v:.3f}" for k, v in mean.items()))
    h = st.compared_mse()
    line = (
        f"{st.compared_label()}, sequential against combined: {compare_methods(h['combined'], h['sequential'])} "
        f"(moving samples: {compare_methods(h['combined_moving_samples'], h['sequential_moving_samples'])})"
    )
    if st.is_paper_arm:
        js = list(st.compared_joints)
        paper = {m: float(np.mean(np.asarray(PAPER_TABLE1_MSE[m])[js])) for m in PAPER_TABLE1_MSE}
        line += f"; paper: {compare_methods(paper['combined'], paper['sequential'])}"
    print(line)
    for m in st.notes["projected"]:  # type: ignore[attr-defined]
        print(f"{m}: the least-squares estimate has no physically consistent set of links near the file's; the saved "
              f"and validated model is the nearest consistent one ({st.results[m].notes[-1]})")  # fmt: skip
    return rows, h


def _save_study(args: argparse.Namespace, out: Path, robot: Any, st: Any, rows: list[Any], h: dict[str, Any]) -> None:
    """The models, their robot copies, the validation log, excitation.json, study.json and the figures."""
    from reflexarm.ident import save_log
    from reflexarm.ident.export.model_file import save_identified_model
    from reflexarm.ident.plots import plot_excitation, plot_friction, plot_torque_validation

    base = st.results["sequential"].base
    rel = {
        m: float(np.linalg.norm(r.beta_b - st.true_base) / np.linalg.norm(st.true_base)) for m, r in st.results.items()
    }
    copies = []
    for m, r in st.results.items():
        save_identified_model(
            r, robot, out / f"model_{m}.json", extra={"scenario": args.scenario, "min_speed": st.min_speed}
        )
        copies.append(write_robot_copy(r, st.nominal, out, args)[0])
    save_log(st.validation_raw, out / "validation_log.npz")
    write_json(out / "excitation.json", {"robot": robot.name, **st.excitation.to_dict()})
    write_json(
        out / "study.json",
        {
            "robot": robot.name,
            "scenario": args.scenario,
            "notes": st.notes,
            "n_base": base.n_base,
            "min_speed": st.min_speed,
            "condition_initial": st.excitation.condition_initial,
            "condition_optimized": st.excitation.condition_optimized,
            "compared_joints": [j + 1 for j in st.compared_joints],
            "compared_mse": h,
            "mean_mse": st.mean_mse(),
            "base_relative_error": rel,
            "friction_fits": st.friction.table(robot.joint_names),
            "table": rows,
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
        f"\nwrote {out}/ (model_combined.json, model_sequential.json: the models above; validation_log.npz: "
        "'reflexarm validate --model model_<method>.json --log validation_log.npz --friction-model identified' "
        "reproduces their columns; "
        "excitation.json, study.json, table1_mse.csv, fig4_friction.png, fig6_torques.png, excitation.png"
        + "".join(f", {c}" for c in copies if c)
        + ": the models above in a copy of the robot file)"
    )
