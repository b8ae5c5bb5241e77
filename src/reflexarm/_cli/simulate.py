"""``reflexarm demo`` and ``reflexarm simulate ...``: the collision experiments of Sec. III-A/B."""

from __future__ import annotations

import argparse
import json
import sys

from reflexarm._cli.common import add_common, format_table, out_dir


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` and ``simulate`` to the top-level parser."""
    p = sub.add_parser(
        "demo",
        help="end-effector collision with a cinderblock on the Atlas arm: Stiff / Compliant / Coll.Det (Figs. 7-8)",
    )
    add_common(p, default_out="results/demo")
    p.set_defaults(func=_demo)

    s = sub.add_parser("simulate", help="run one of the paper's simulated collision experiments")
    ssub = s.add_subparsers(dest="experiment", metavar="EXPERIMENT")
    ssub.required = True
    e = ssub.add_parser("ee-collision", help="the demo's experiment (Figs. 7-8)")
    add_common(e, default_out="results/ee-collision")
    e.set_defaults(func=_demo)
    lc = ssub.add_parser("link-collision", help="a stick pushes the elbow during a joint motion (Figs. 9-10)")
    add_common(lc, default_out="results/link-collision")
    lc.set_defaults(func=_link)
    fm = ssub.add_parser("free-motion", help="false-alarm check: the demo trajectory without obstacle")
    add_common(fm, default_out="results/free-motion")
    fm.add_argument("--duration", type=float, default=60.0, help="simulated time [s] (default 60)")
    fm.add_argument("--threshold", type=float, default=11.0, help="zeta [Nm] (default 11)")
    fm.set_defaults(func=_free)


def _demo(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import EE_SETTINGS, run_ee_collision, summarize_ee_collision, write_outputs
    from reflexarm.experiments.plots import plot_fig8

    out = out_dir(args)
    traces, rows = [], []
    for setting in EE_SETTINGS:
        detection = (
            "off"
            if setting.threshold is None
            else f"zeta = {setting.threshold:g} Nm, k_o = {setting.observer_gain:g} 1/s"
        )
        print(
            f"[{setting.name}] k = {setting.stiffness:g} Nm/rad, detection {detection}",
            file=sys.stderr,
        )
        tr = run_ee_collision(setting, seed=args.seed, progress=not args.quiet)
        traces.append(tr)
        rows.append(summarize_ee_collision(tr))
    write_outputs(out, "ee_collision", traces, rows)
    fig = plot_fig8(traces, out / "fig8_ee_collision.png")
    print(
        format_table(
            rows,
            [
                ("run", "run", "{}"),
                ("peak_force_N", "peak |f| [N]", "{:.1f}"),
                ("quasi_static_force_N", "quasi-static |f| [N]", "{:.1f}"),
                ("final_force_N", "final |f| [N]", "{:.1f}"),
                ("first_contact_s", "contact [s]", "{:.3f}"),
                ("detection_s", "detected [s]", "{:.3f}"),
                ("detection_delay_s", "delay [s]", "{:.3f}"),
                ("block_displacement_m", "block moved [m]", "{:.3f}"),
                ("block_tipped", "tipped", "{}"),
                ("final_q1_error_rad", "|q1 err| end [rad]", "{:.3f}"),
            ],
        )
    )
    print(f"\nwrote {out}/ (traces *.npz, ee_collision_summary.json, {fig.name})")
    return 0


def _link(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import (
        model_torque,
        run_link_collision,
        summarize_link_collision,
        write_outputs,
    )
    from reflexarm.experiments.plots import plot_fig10

    out = out_dir(args)
    tr = run_link_collision(seed=args.seed, progress=not args.quiet)
    row = summarize_link_collision(tr)
    write_outputs(out, "link_collision", [tr], [row])
    fig = plot_fig10(tr, model_torque(tr), out / "fig10_link_collision.png")
    print(
        format_table(
            [row],
            [
                ("contact_start_s", "contact [s]", "{:.3f}"),
                ("detection_s", "detected [s]", "{:.3f}"),
                ("detection_delay_s", "delay [s]", "{:.3f}"),
                ("detected_joints", "joints (0-based)", "{}"),
                ("peak_external_torque_Nm", "peak |tau_ext| [Nm]", "{:.1f}"),
            ],
        )
    )
    print(f"\nwrote {out}/ (trace, link_collision_summary.json, {fig.name})")
    return 0


def _free(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import free_motion_false_alarms

    out = out_dir(args)
    res = free_motion_false_alarms(args.duration, threshold=args.threshold, seed=args.seed, progress=not args.quiet)
    (out / "free_motion.json").write_text(json.dumps(res, indent=2))
    print(json.dumps(res, indent=2))
    return 0
