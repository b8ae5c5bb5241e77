"""``reflexarm efc-step | compliance-loss | mode-table | sweep {model-error,noise}``: Sec. III-C, Figs. 3, 11-14."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from reflexarm._cli.common import add_common, format_table, out_dir


def _add_setup_options(p: argparse.ArgumentParser, friction: str) -> None:
    p.add_argument(
        "--plant-friction",
        choices=("dry", "smooth", "none"),
        default=friction,
        help="true arm's joint friction: smooth = continuous-time Coulomb + viscous, Table I, no stiction (the "
        "paper's simulation); dry = MuJoCo frictionloss with stiction (Table I, like the real arm); none "
        f"(default {friction})",
    )
    p.add_argument("--model-error", type=float, default=10.0, help="+- model errors [%%] (default 10)")
    p.add_argument("--noise-scale", type=float, default=1.0, help="factor on the paper's sensor noise (default 1)")


def _setup(args: argparse.Namespace) -> Any:
    from reflexarm.errors import ConfigError
    from reflexarm.experiments.compensation import CompensationSetup

    if args.model_error < 0:
        raise ConfigError(f"--model-error must be non-negative [%]; got {args.model_error:g}")
    if args.noise_scale < 0:
        raise ConfigError(f"--noise-scale must be non-negative; got {args.noise_scale:g}")
    return CompensationSetup(
        model_error=args.model_error / 100.0, noise_scale=args.noise_scale, plant_friction=args.plant_friction
    )


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``efc-step``, ``compliance-loss``, ``mode-table`` and ``sweep`` to the top-level parser."""
    p = sub.add_parser("efc-step", help="50 N step on the end effector: no DC / DC / DC+EFC (Fig. 12)")
    add_common(p, default_out="results/efc-step")
    _add_setup_options(p, "smooth")
    p.set_defaults(func=_efc_step)

    p = sub.add_parser("compliance-loss", help="push the end effector and hold it, with and without DC (Fig. 11)")
    add_common(p, default_out="results/compliance-loss")
    _add_setup_options(p, "dry")
    p.add_argument("--depth", type=float, default=0.10, help="travel of the pushing hand [m] (default 0.10)")
    p.add_argument("--hand-stiffness", type=float, default=2000.0, help="the hand's stiffness [N/m] (default 2000)")
    p.set_defaults(func=_compliance_loss)

    p = sub.add_parser("mode-table", help="the table of Fig. 3, measured for each control mode")
    add_common(p, default_out="results/mode-table")
    _add_setup_options(p, "dry")
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
        _add_setup_options(k, "smooth")
        k.add_argument("--levels", default=None, help=f"{levels_help}; 'a:b[:step]' or 'a,b,c'")
        k.add_argument("--trials", type=int, default=10, help="random draws per level (default 10)")
        k.add_argument("--workers", type=int, default=None, help="local worker processes (default: every core)")
        k.add_argument("--scheduler", metavar="ADDRESS", default=None, help="run on this Dask scheduler instead")
        k.set_defaults(func=_sweep, kind=kind)


def _print_rows(rows: list[dict[str, Any]], columns: list[tuple[str, str, str]]) -> None:
    print(format_table(rows, columns))


def _efc_step(args: argparse.Namespace) -> int:
    from reflexarm.experiments.compensation import efc_step, plot_efc_step, write_json

    out = out_dir(args)
    setup = _setup(args)
    t0 = time.perf_counter()
    res = efc_step(setup, seed=args.seed, progress=not args.quiet)
    for name, tr in res.traces.items():
        tr.save(out / f"efc_step_{name.replace(' ', '_').replace(',', '').replace('+', 'plus')}.npz")
    fig = plot_efc_step(res, out / "fig12_efc_step.png")
    write_json(out / "efc_step.json", {"setup": setup.as_dict(), "rows": res.rows, "summary": res.summary})
    _print_rows(
        res.rows,
        [
            ("run", "run", "{}"),
            ("ee_displacement_mm", "EE displ. [mm]", "{:.1f}"),
            ("q1_displacement_rad", "dq_1 [rad]", "{:.4f}"),
            ("tau_ext1_Nm", "tau_ext,1 [Nm]", "{:.2f}"),
            ("residual1_Nm", "res_1 [Nm]", "{:.2f}"),
            ("residual_norm_Nm", "|res| [Nm]", "{:.2f}"),
            ("max_abs_residual_Nm", "max|res| [Nm]", "{:.1f}"),
            ("ee_after_release_mm", "EE after release [mm]", "{:.1f}"),
        ],
    )
    s = res.summary
    print(
        f"\nsteady state under the load ({setup.load_window[0]:g}-{setup.load_window[1]:g} s):\n"
        f"  EE displacement  DC+EFC / no DC = {s['efc_vs_nodc_displacement']:.3f}   (paper: ~1; q_1 alone: "
        f"{s['efc_vs_nodc_q1']:.3f})\n"
        f"  EE displacement  DC / no DC     = {s['dc_vs_nodc_displacement']:.4f}  (paper: stiff, (10))\n"
        f"  residual_1       DC+EFC / DC    = {s['efc_vs_dc_residual1']:.4f}  "
        f"(all joints, norm: {s['efc_vs_dc_residual_norm']:.3f})\n"
        f"  30 Nm cut-off: peak DC residual {s['peak_dc_residual_Nm']:.1f} Nm; share of the DC displacement it "
        f"explains: {100 * s['cutoff_share_of_dc_displacement']:.1f} %\n"
        f"plant friction: {setup.plant_friction}; wrote {out}/ ({fig.name}, efc_step.json, traces) in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    return 0


def _compliance_loss(args: argparse.Namespace) -> int:
    from reflexarm.experiments.compensation import compliance_loss, plot_compliance_loss, write_json

    out = out_dir(args)
    setup = _setup(args)
    res = compliance_loss(
        setup, depth=args.depth, hand_stiffness=args.hand_stiffness, seed=args.seed, progress=not args.quiet
    )
    fig = plot_compliance_loss(res, out / "fig11_compliance_loss.png")
    write_json(
        out / "compliance_loss.json",
        {"setup": setup.as_dict(), "push": res.push, "rows": res.rows, "summary": res.summary},
    )
    _print_rows(
        res.rows,
        [
            ("run", "run", "{}"),
            ("residual_limit_Nm", "cut-off [Nm]", "{:g}"),
            ("force_N", "|f| [N]", "{:.1f}"),
            ("displacement_mm", "dx along push [mm]", "{:.1f}"),
            ("apparent_stiffness_N_per_m", "|f|/dx [N/m]", "{:.0f}"),
            ("residual1_Nm", "res_1 [Nm]", "{:.1f}"),
        ],
    )
    s = res.summary
    print(
        f"\nwith DC / without: force x{s['force_ratio']:.2f} (paper 1.93), displacement x"
        f"{s['displacement_ratio']:.2f} (paper 0.67), apparent stiffness x{s['stiffness_ratio']:.2f} "
        f"(paper 2.87)\nwithout the 30 Nm cut-off the stiffness would rise x{s['stiffness_ratio_no_cutoff']:.0f}\n"
        f"wrote {out}/ ({fig.name}, compliance_loss.json)"
    )
    return 0


def _mark(v: bool) -> str:
    return "yes" if v else "no"


def _mode_table(args: argparse.Namespace) -> int:
    from reflexarm.experiments.compensation import CHECK_RATIO, mode_table, write_json

    out = out_dir(args)
    setup = _setup(args)
    rows, _ = mode_table(setup, seed=args.seed, progress=not args.quiet)
    write_json(out / "mode_table.json", {"setup": setup.as_dict(), "check_ratio": CHECK_RATIO, "rows": rows})
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
        f"'link, auto-switch': the same link push with detection (zeta = 11 Nm) and the supervisor switching to "
        f"the compliant mode.\nwrote {out}/mode_table.json"
    )
    return 0 if all(r["agrees_with_paper"] for r in rows) else 1


def _sweep(args: argparse.Namespace) -> int:
    from reflexarm.experiments.sweeps import DEFAULT_LEVELS, paper_sweep

    out = out_dir(args)
    setup = _setup(args)
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
    s = res.summary
    wide = s.pivot(index="level", columns="condition", values="norm_mean")
    rows = [
        {
            "level": lv,
            "dc": wide.loc[lv, "DC"],
            "efc": wide.loc[lv, "DC+EFC"],
            "ratio": wide.loc[lv, "DC"] / wide.loc[lv, "DC+EFC"],
        }
        for lv in wide.index
    ]
    unit = "%" if args.kind == "model-error" else "x"
    _print_rows(
        rows,
        [
            ("level", f"level [{unit}]", "{:g}"),
            ("dc", "||MSIE|| DC", "{:.4f}"),
            ("efc", "||MSIE|| DC+EFC", "{:.4f}"),
            ("ratio", "DC / DC+EFC", "{:.1f}"),
        ],
    )
    n_div = int(s["diverged"].sum())
    print(
        f"\n{len(res.sweep.table)} runs ({len(res.sweep.ran)} run now, {len(res.sweep.skipped)} found in {out}), "
        f"{n_div} diverged; wall {wall:.1f} s"
    )
    if res.sweep.run_wall_s:
        mean_run = sum(res.sweep.run_wall_s.values()) / len(res.sweep.run_wall_s)
        print(f"mean wall time of one run: {mean_run:.2f} s")
    files = ", ".join(p.name for p in res.files.values())
    print(f"wrote {out}/ ({files}, runs/)")
    (out / "last_call.json").write_text(json.dumps({"argv": sys.argv[1:], "wall_s": wall}, indent=2))
    return 0
