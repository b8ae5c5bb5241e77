"""``reflexarm efc-step | compliance-loss | mode-table | sweep {model-error,noise}``: Sec. III-C, Figs. 3, 11-14."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from reflexarm._cli.common import (
    add_common,
    add_detection_options,
    add_model_options,
    detection_choice,
    format_table,
    model_error_percent,
    out_dir,
    tuned_gain_note,
)
from reflexarm._cli.robot_options import add_robot_options, robot_kwargs
from reflexarm._cli.run_outputs import SceneCapture, add_output_options, write_traces


def _add_setup_options(p: argparse.ArgumentParser, friction: str, kappa_f: int) -> None:
    p.add_argument(
        "--plant-friction",
        choices=("dry", "smooth", "none"),
        default=friction,
        help="true arm's joint friction: smooth = continuous-time Coulomb + viscous, Table I, no stiction (the "
        "paper's simulation); dry = MuJoCo frictionloss with stiction (Table I, like the real arm); none "
        f"(default {friction})",
    )
    p.add_argument(
        "--kappa-f",
        type=int,
        choices=(0, 1),
        default=kappa_f,
        help="friction compensation in (2) and (6): 1 in the paper's simulation (its model errors scale the "
        f"friction coefficients), 0 in its experiments on the real arm (default {kappa_f})",
    )
    add_model_options(
        p,
        default_error=10.0,
        default_seed=None,
        seed_help="seed of the model-error draw (default: derived from --seed, as each trial of a sweep)",
    )
    p.add_argument("--noise-scale", type=float, default=1.0, help="factor on the paper's sensor noise (default 1)")
    add_robot_options(p)


def _setup(args: argparse.Namespace, **overrides: Any) -> Any:
    from reflexarm.errors import ConfigError
    from reflexarm.experiments.compensation import CompensationSetup, robot_options

    pct = model_error_percent(args)
    if args.noise_scale < 0:
        raise ConfigError(f"--noise-scale must be non-negative; got {args.noise_scale:g}")
    return CompensationSetup(
        model_error=pct / 100.0,
        noise_scale=args.noise_scale,
        plant_friction=args.plant_friction,
        kappa_f=args.kappa_f,
        model_file=None if args.model is None else str(args.model),
        robot=str(args.robot),
        robot_options=robot_options(robot_kwargs(args)),
        **overrides,
    )


def _model_label(setup: Any, model_seed: int | None) -> str:
    if setup.model_file is not None:
        return f"identified model {setup.model_file}"
    if setup.model_error == 0.0:
        return "the plant's exact model"
    seed = "derived from --seed" if model_seed is None else str(model_seed)
    return f"+-{100 * setup.model_error:g} % model errors (seed {seed})"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``efc-step``, ``compliance-loss``, ``mode-table`` and ``sweep`` to the top-level parser."""
    p = sub.add_parser("efc-step", help="50 N step on the end effector: no DC / DC / DC+EFC (Fig. 12)")
    add_common(p, default_out="results/efc-step")
    _add_setup_options(p, "smooth", 1)
    add_output_options(p)
    p.set_defaults(func=_efc_step)

    p = sub.add_parser("compliance-loss", help="push the end effector and hold it, with and without DC (Fig. 11)")
    add_common(p, default_out="results/compliance-loss")
    _add_setup_options(p, "dry", 0)
    p.add_argument("--depth", type=float, default=0.10, help="travel of the pushing hand [m] (default 0.10)")
    p.add_argument(
        "--hand-stiffness",
        default="500,1000,2000,3000,5000,10000",
        help="the pushing hand's stiffness [N/m], one value or a list to sweep (the paper gives none; default "
        "500,1000,2000,3000,5000,10000)",
    )
    add_output_options(p)
    p.set_defaults(func=_compliance_loss)

    p = sub.add_parser("mode-table", help="the table of Fig. 3, measured for each control mode")
    add_common(p, default_out="results/mode-table")
    _add_setup_options(p, "dry", 0)
    add_detection_options(
        p,
        observer_gain=None,
        reaction="compliant",
        note="the supervised link push; --observer-gain default: the setup's 10 1/s (Sec. III-C)",
    )
    add_output_options(p)
    p.set_defaults(func=_mode_table)

    s = sub.add_parser("sweep", help="robustness sweeps: model errors (Fig. 13) or sensor noise (Fig. 14)")
    ssub = s.add_subparsers(dest="sweep", metavar="SWEEP")
    ssub.required = True
    for kind, fig, levels_help in (
        ("model-error", "Fig. 13", "model-error levels in %% (default 1:30, i.e. 1, 2, ..., 30)"),
        ("noise", "Fig. 14", "noise scale factors (default 1:30)"),
    ):
        k = ssub.add_parser(kind, help=f"{fig}: normalised MSIE (20) over the level, DC without and with EFC")
        add_common(k, default_out=f"results/sweep-{kind}")
        _add_setup_options(k, "smooth", 1)
        k.add_argument(
            "--noise-channels",
            default=None,
            help="noise only on these sensor channels (comma list of q, dq, gravity, tau_m, force, torque; default "
            "all, as the paper): a diagnostic of which channel drives an effect",
        )
        k.add_argument("--levels", default=None, help=f"{levels_help}; 'a:b[:step]' or 'a,b,c'")
        k.add_argument("--trials", type=int, default=10, help="random draws per level (default 10)")
        k.add_argument("--workers", type=int, default=None, help="local worker processes (default: every core)")
        k.add_argument("--scheduler", metavar="ADDRESS", default=None, help="run on this Dask scheduler instead")
        k.set_defaults(func=_sweep, kind=kind)


def _print_rows(rows: list[dict[str, Any]], columns: list[tuple[str, str, str]]) -> None:
    print(format_table(rows, columns))


def _efc_step(args: argparse.Namespace) -> int:
    from reflexarm.experiments.compensation import write_json
    from reflexarm.experiments.efc_step import efc_step
    from reflexarm.experiments.plots import plot_efc_step

    out = out_dir(args)
    setup = _setup(args)
    t0 = time.perf_counter()
    with SceneCapture(args, out, "efc_step") as scene:
        res = efc_step(setup, seed=args.seed, model_seed=args.model_seed, progress=not args.quiet)
    write_traces(out, "efc_step", res.traces)
    fig = plot_efc_step(res, out / "fig12_efc_step.png")
    write_json(out / "efc_step.json", {"setup": setup.as_dict(), "rows": res.rows, "summary": res.summary})
    pictures = scene.finish(list(res.traces), summary=out / "efc_step.json")
    _print_rows(
        res.rows,
        [
            ("run", "run", "{}"),
            ("ee_displacement_mm", "EE displ. [mm]", "{:.1f}"),
            ("q_loaded_displacement_rad", f"dq_{res.joint + 1} [rad]", "{:.4f}"),
            ("tau_ext_loaded_Nm", f"tau_ext,{res.joint + 1} [Nm]", "{:.2f}"),
            ("residual_loaded_Nm", f"res_{res.joint + 1} [Nm]", "{:.2f}"),
            ("residual_norm_Nm", "|res| [Nm]", "{:.2f}"),
            ("max_abs_residual_Nm", "max|res| [Nm]", "{:.1f}"),
            ("ee_after_release_mm", "EE after release [mm]", "{:.1f}"),
        ],
    )
    s = res.summary
    j = res.joint + 1
    tau = ", ".join(f"{x:.2f}" for x in s["tau_ext_Nm"])
    print(
        f"\nloaded joint: {j} ({s['loaded_joint_name']}), the largest |tau_ext| under the load (per joint: {tau} "
        f"Nm); its q, tau_ext and residual are in the table and the figure\n"
        f"steady state under the load ({setup.load_window[0]:g}-{setup.load_window[1]:g} s):\n"
        f"  EE displacement  DC+EFC / no DC = {s['efc_vs_nodc_displacement']:.3f}   (paper: ~1; q_{j} alone: "
        f"{s['efc_vs_nodc_q_loaded']:.3f})\n"
        f"  EE displacement  DC / no DC     = {s['dc_vs_nodc_displacement']:.4f}  (paper: stiff, (10))\n"
        f"  residual_{j}       DC+EFC / DC    = {s['efc_vs_dc_residual_loaded']:.4f}  "
        f"(all joints, norm: {s['efc_vs_dc_residual_norm']:.3f})\n"
        f"  30 Nm cut-off: peak DC residual {s['peak_dc_residual_Nm']:.1f} Nm; share of the DC displacement it "
        f"explains: {100 * s['cutoff_share_of_dc_displacement']:.1f} %\n"
        f"controller: {_model_label(setup, args.model_seed)}, kappa_f = {setup.kappa_f}; plant friction: "
        f"{setup.plant_friction}; wrote {out}/ ({fig.name}, efc_step.json, traces) in "
        f"{time.perf_counter() - t0:.1f} s\n{SceneCapture.describe(pictures)}"
    )
    return 0


def _compliance_loss(args: argparse.Namespace) -> int:
    from reflexarm.errors import ConfigError
    from reflexarm.experiments.compensation import write_json
    from reflexarm.experiments.compliance_loss import PAPER_FIG11, compliance_loss_sweep
    from reflexarm.experiments.plots import plot_compliance_loss, plot_compliance_sweep
    from reflexarm.experiments.sweeps import parse_levels

    out = out_dir(args)
    setup = _setup(args)
    stiffness = parse_levels(args.hand_stiffness, name="--hand-stiffness")
    if any(k <= 0 for k in stiffness):
        raise ConfigError(f"--hand-stiffness must be positive [N/m]; got {args.hand_stiffness}")
    with SceneCapture(args, out, "compliance_loss") as scene:
        sweep = compliance_loss_sweep(
            stiffness, setup, depth=args.depth, seed=args.seed, model_seed=args.model_seed, progress=not args.quiet
        )
    traces = {
        f"k{k:g}/{name}": tr for k, res in zip(stiffness, sweep.results, strict=True) for name, tr in res.traces.items()
    }
    write_traces(out, "compliance_loss", traces)
    rows = sweep.rows()
    for k, res in zip(stiffness, sweep.results, strict=True):
        plot_compliance_loss(res, out / f"fig11_compliance_loss_k{k:g}.png")
    fig = plot_compliance_sweep(sweep, out / "fig11_hand_stiffness.png")
    write_json(
        out / "compliance_loss.json",
        {
            "setup": setup.as_dict(),
            "push": sweep.results[0].push,
            "rows": rows,
            "runs": {f"{k:g}": res.rows for k, res in zip(stiffness, sweep.results, strict=True)},
            "paper": PAPER_FIG11,
        },
    )
    pictures = scene.finish(list(traces), summary=out / "compliance_loss.json")
    _print_rows(
        rows,
        [
            ("hand_stiffness_N_per_m", "hand [N/m]", "{:g}"),
            ("force_no_dc_N", "|f| no DC [N]", "{:.1f}"),
            ("force_dc_N", "|f| DC [N]", "{:.1f}"),
            ("displacement_no_dc_mm", "dx no DC [mm]", "{:.1f}"),
            ("displacement_dc_mm", "dx DC [mm]", "{:.1f}"),
            ("force_ratio", "force DC/noDC", "{:.2f}"),
            ("paper_force_ratio", "paper", "{:.2f}"),
            ("displacement_ratio", "displ. DC/noDC", "{:.2f}"),
            ("paper_displacement_ratio", "paper", "{:.2f}"),
            ("stiffness_ratio", "stiffn. DC/noDC", "{:.2f}"),
            ("paper_stiffness_ratio", "paper", "{:.2f}"),
            ("stiffness_ratio_no_cutoff", "no cut-off", "{:.0f}"),
            ("peak_dc_residual_Nm", "peak |res| DC [Nm]", "{:.1f}"),
        ],
    )
    print(
        f"\nratios with DC / without DC under the hold (paper: force +93 % = x1.93, displacement 67 % = x0.67, "
        f"stiffness +187 % = x{PAPER_FIG11['stiffness_ratio']:.2f}); 'no cut-off': the stiffness ratio without "
        f"the 30 Nm cut-off (bounded by the joints' effort limits once the push needs more torque).\n"
        "A hand too soft to drive the residual past the cut-off is cancelled by DC as (10) says (the arm holds); "
        "a firmer one passes the cut-off and the arm yields beyond it.\n"
        f"controller: {_model_label(setup, args.model_seed)}, kappa_f = {setup.kappa_f}; "
        f"plant friction: {setup.plant_friction}\nwrote {out}/ ({fig.name}, fig11_compliance_loss_k*.png, "
        f"compliance_loss.json, traces compliance_loss_k*.npz)\n{SceneCapture.describe(pictures)}"
    )
    return 0


def _mark(v: bool) -> str:
    return "yes" if v else "no"


def _mode_table(args: argparse.Namespace) -> int:
    from reflexarm.experiments.compensation import write_json
    from reflexarm.experiments.mode_table import CHECK_RATIO, mode_table
    from reflexarm.experiments.plots import plot_mode_table

    out = out_dir(args)
    overrides = {} if args.observer_gain is None else {"observer_gain": args.observer_gain}
    setup = _setup(args, **overrides)
    from reflexarm.experiments.compensation import true_robot

    detection = detection_choice(args, true_robot(setup))
    print(f"supervised link push: detection {detection.label()}, k_o = {setup.observer_gain:g} 1/s", file=sys.stderr)
    note = tuned_gain_note(detection, setup.observer_gain)
    if note:
        print(note, file=sys.stderr)
    with SceneCapture(args, out, "mode_table") as scene:
        rows, traces = mode_table(
            setup,
            seed=args.seed,
            model_seed=args.model_seed,
            progress=not args.quiet,
            threshold=detection.threshold,
            detection_observer_gain=detection.detection_observer_gain,
            reaction=detection.reaction,
            detection_friction_band=detection.detection_friction_band,
            reaction_settings=detection.reaction_settings,
            detection_filter_gain=detection.detection_filter_gain,
        )
    write_json(
        out / "mode_table.json",
        {"setup": setup.as_dict(), "check_ratio": CHECK_RATIO, "detection": detection.describe(), "rows": rows},
    )
    write_traces(out, "mode_table", traces)
    fig = plot_mode_table(rows, CHECK_RATIO, out / "fig3_mode_table.png")
    pictures = scene.finish(list(traces), summary=out / "mode_table.json")
    table = []
    for r in rows:
        table.append(
            {
                "mode": r["mode"],
                "kappa": f"eps={r['kappa_eps']}, ext={r['kappa_ext']}",
                "acc": f"{r['accuracy_ratio']:.3f} ({1e3 * r['tracking_rms_rad']:.1f} mrad) {_mark(r['accurate'])} / "
                f"{_mark(r['paper_accurate'])}",
                "ee": f"{r['ee_compliance_ratio']:.3f} {_mark(r['ee_compliant'])} / {_mark(r['paper_ee_compliant'])}",
                "link": f"{r['link_compliance_ratio']:.3f} {_mark(r['link_compliant'])} / "
                f"{_mark(r['paper_link_compliant'])}",
                "sup": f"{r['link_compliance_supervised_ratio']:.3f} {_mark(r['link_compliant_supervised'])}",
                "loop": r["closed_loop"],
                "agree": _mark(r["agrees_with_paper"]),
            }
        )
    _print_rows(
        table,
        [
            ("mode", "mode", "{}"),
            ("kappa", "switches", "{}"),
            ("acc", "increased accuracy: ratio measured/paper", "{}"),
            ("ee", "EE compliance", "{}"),
            ("link", "link compliance", "{}"),
            ("sup", "link, auto-switch", "{}"),
            ("loop", "closed loop", "{}"),
            ("agree", "agrees", "{}"),
        ],
    )
    print(
        f"\naccuracy ratio: RMS tracking error / compliant mode's (check mark if <= {CHECK_RATIO}); compliance "
        f"ratios: measured displacement / J K^-1 J^T f (check mark if >= {CHECK_RATIO}).\n"
        f"'link, auto-switch': the same link push with detection ({detection.label()}) and the supervisor's "
        "reaction (default: the switch to the compliant mode).\n"
        f"wrote {out}/ (mode_table.json, {fig.name}, traces mode_table_*.npz)\n"
        f"{SceneCapture.describe(pictures)}"
    )
    return 0 if all(r["agrees_with_paper"] for r in rows) else 1


def _sweep_table(summary: Any, kind: str, model_error: float) -> tuple[list[dict[str, Any]], list[tuple]]:
    """The rows (one per level, DC beside DC+EFC) and columns of the sweep's printed table."""
    s = summary
    by = {c: s[s["condition"] == c].set_index("level") for c in ("DC", "DC+EFC")}
    dc, efc = by["DC"], by["DC+EFC"]
    rows = []
    for lv in dc.index:
        row: dict[str, Any] = {
            "level": lv,
            "dc": dc.loc[lv, "norm_mean"],
            "efc": efc.loc[lv, "norm_mean"],
            "ratio": dc.loc[lv, "msie_mean"] / efc.loc[lv, "msie_mean"],
            "dc_abs": dc.loc[lv, "msie_mean"],
            "efc_abs": efc.loc[lv, "msie_mean"],
        }
        for key in s.columns:
            if key in dc.columns and key not in ("n", "condition") and not key.startswith(("norm_", "msie_")):
                row[f"dc_{key}"] = dc.loc[lv, key]
        rows.append(row)
    unit = "%" if kind == "model-error" else "x"
    columns = [
        ("level", f"level [{unit}]", "{:g}"),
        ("dc", "||MSIE|| DC", "{:.4f}"),
        ("efc", "||MSIE|| DC+EFC", "{:.5f}"),
        ("ratio", "DC/DC+EFC", "{:.1f}"),
        ("dc_abs", "MSIE DC [rad^2]", "{:.4e}"),
        ("efc_abs", "MSIE DC+EFC [rad^2]", "{:.4e}"),
    ]
    if kind == "model-error" or model_error > 0:
        columns += [
            ("dc_g_error_median", "g err med", "{:.2%}"),
            ("dc_g_error_max", "g err max", "{:.1%}"),
            ("dc_M_error_median", "M err med", "{:.2%}"),
            ("dc_M_error_max", "M err max", "{:.1%}"),
        ]
    if kind == "noise":
        columns += [
            ("dc_residual1_load_std_Nm", "std res1 [Nm]", "{:.2f}"),
            ("dc_residual1_noise_pred_Nm", "pred. std", "{:.2f}"),
            ("dc_residual1_clip_fraction", "|res1|>cut", "{:.3f}"),
            ("dc_compensated1_load_Nm", "mean cut res1", "{:.2f}"),
            ("dc_tau_ext1_load_Nm", "tau_ext1 [Nm]", "{:.2f}"),
        ]
    return rows, columns


def _sweep(args: argparse.Namespace) -> int:
    from reflexarm.errors import ConfigError
    from reflexarm.experiments.plots import crossover_levels
    from reflexarm.experiments.robustness import DEFAULT_LEVELS, paper_sweep

    out = out_dir(args)
    channels = None
    if args.noise_channels is not None:
        channels = tuple(c.strip() for c in args.noise_channels.split(",") if c.strip())
    if args.kind == "model-error" and args.model is not None:
        raise ConfigError(
            f"--model {args.model}: a model-error sweep perturbs the true model at each level; use --model with "
            "'sweep noise'"
        )
    if args.model_seed is not None:
        raise ConfigError(
            f"--model-seed {args.model_seed}: a sweep draws one model per trial from --seed; drop --model-seed"
        )
    setup = _setup(args, noise_channels=channels)
    levels = DEFAULT_LEVELS[args.kind] if args.levels is None else args.levels
    t0 = time.perf_counter()
    res = paper_sweep(
        args.kind,
        out,
        levels=levels,
        trials=args.trials,
        seed=args.seed,
        setup=setup,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.quiet,
    )
    wall = time.perf_counter() - t0
    rows, columns = _sweep_table(res.summary, args.kind, setup.model_error)
    s = res.summary
    _print_rows(rows, columns)
    if args.kind == "model-error":
        print(
            "\ng/M err: achieved relative error of the controller's g(q) and M(q) (median and max over 100 random "
            "states, mean over the trials)"
        )
    else:
        cross = crossover_levels(s)
        print(
            "\njoint 1 under the load, DC run: std of the residual (measured; predicted from the velocity noise, "
            "k_o |M_1,:| a_dq s / sqrt(3)), share of ticks beyond the cut-off, mean of the cut-off residual, "
            f"tau_ext,1\ncrossover (DC below DC+EFC): {'at ' + ', '.join(f'{c:g}' for c in cross) if cross else 'none'}"
        )
    n_div = int(s["diverged"].sum())
    model = (
        "model errors of each level, one draw per trial (from --seed)"
        if args.kind == "model-error"
        else f"{_model_label(setup, None)}, one draw per trial"
    )
    print(
        f"controller: {model}, kappa_f = {setup.kappa_f}; plant friction: "
        f"{setup.plant_friction}; noise channels: {'all' if channels is None else ', '.join(channels)}\n"
        f"{len(res.sweep.table)} runs ({len(res.sweep.ran)} run now, {len(res.sweep.skipped)} found in {out}), "
        f"{n_div} diverged; wall {wall:.1f} s"
    )
    if res.sweep.run_wall_s:
        mean_run = sum(res.sweep.run_wall_s.values()) / len(res.sweep.run_wall_s)
        print(f"mean wall time of one run: {mean_run:.2f} s")
    files = ", ".join(p.name for p in res.files.values())
    print(f"wrote {out}/ ({files}, runs/)")
    (out / "last_call.json").write_text(json.dumps({"argv": sys.argv[1:], "wall_s": wall}, indent=2))
    return 0
