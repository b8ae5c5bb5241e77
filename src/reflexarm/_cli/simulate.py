"""``reflexarm demo`` and ``reflexarm simulate ...``: the collision experiments of Sec. III-A/B."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from reflexarm._cli.collision_settings import setting_line, with_detection
from reflexarm._cli.common import (
    DetectionChoice,
    add_common,
    add_detection_options,
    add_model_options,
    detection_choice,
    format_table,
    model_choice,
    model_error_line,
    out_dir,
    tuned_gain_note,
)
from reflexarm._cli.robot_options import add_robot_options, load_robot_from_args
from reflexarm._cli.run_outputs import (
    SceneCapture,
    add_output_options,
    fault_line,
    fault_record,
    number_joints,
    write_json,
    write_traces,
)

_PAPER_COLUMNS = [("quantity", "", "{}"), ("paper", "paper", "{}"), ("ours", "ours", "{}")]

_DEPTH_HELP = (
    "arms other than Atlas: the block stands across the end effector's path where the rest of the path would "
    "run this deep into it [m] (default 0.12; Atlas keeps the paper's block position)"
)

_FRICTION_HELP = (
    "the true arm's joint friction: file (the robot file's Coulomb frictionloss and viscous damping; Atlas: "
    "Table I) or none (no joint friction or damping: nothing but the controller stops the arm; the controller's "
    "model is unchanged) (default file)"
)

#: The columns of the collision event (experiments.collision_events) added to the printed tables.
_EVENT_COLUMNS = [
    ("ke_ratio", "KE +0.5 s / det", "{:.3g}"),
    ("moved_m", "moved after det [m]", "{:.3f}"),
    ("recontact", "re-contact", "{}"),
]

_BLOCK_HELP = (
    "cinderblock variant: paper (0.39 x 0.19 x 0.19 m, 20 kg, table friction 0.6: the Stiff arm slides it) or "
    "tipping (0.29 m tall, table friction 0.9: the Stiff arm tips it over as in Fig. 7 b) (default paper)"
)


def _add_link_collision(ssub: argparse._SubParsersAction) -> None:
    """``simulate link-collision``."""
    lc = ssub.add_parser("link-collision", help="a stick pushes the elbow during a joint motion (Figs. 9-10)")
    add_common(lc, default_out="results/link-collision")
    add_model_options(lc)
    add_robot_options(lc)
    add_output_options(lc)
    lc.add_argument(
        "--link",
        default=None,
        help="the link the stick pushes: a joint number, 1-based (its link), or a link name (default: Atlas' elbow "
        "l_larm; other arms the link of joint ceil(n/2))",
    )
    lc.add_argument("--plant-friction", choices=("file", "none"), default="file", help=_FRICTION_HELP)
    lc.add_argument(
        "--stick",
        choices=("pushed", "held"),
        default="pushed",
        help="pushed: the paper's stick, pushed into the moving link at 50 mm/s for 1.5 s (it keeps coming after a "
        "detection); held: it stands still where the pushed one starts, and the link runs into it (default pushed)",
    )
    add_detection_options(lc)
    lc.set_defaults(func=_link)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` and ``simulate`` to the top-level parser."""
    _add_ee_collision(
        sub,
        "demo",
        "end-effector collision with a cinderblock (Atlas arm by default, or --robot): Stiff / Compliant / "
        "Coll.Det (Figs. 7-8)",
        "results/demo",
    )
    s = sub.add_parser("simulate", help="run one of the paper's simulated collision experiments")
    ssub = s.add_subparsers(dest="experiment", metavar="EXPERIMENT")
    ssub.required = True
    _add_ee_collision(ssub, "ee-collision", "the demo's experiment (Figs. 7-8)", "results/ee-collision")
    _add_link_collision(ssub)
    _add_free_motion(ssub)
    _add_velocity_tracking(ssub)


def _add_ee_collision(sub: argparse._SubParsersAction, name: str, help: str, default_out: str) -> None:
    """``demo`` and ``simulate ee-collision`` (the same experiment and options under two names)."""
    p = sub.add_parser(name, help=help)
    add_common(p, default_out=default_out)
    add_model_options(p)
    add_robot_options(p)
    add_output_options(p)
    p.add_argument("--block", choices=("paper", "tipping"), default="paper", help=_BLOCK_HELP)
    p.add_argument("--depth", type=float, default=0.12, help=_DEPTH_HELP)
    p.add_argument("--plant-friction", choices=("file", "none"), default="file", help=_FRICTION_HELP)
    add_detection_options(p, note="the Coll.Det run; Stiff and Compliant run without detection")
    p.set_defaults(func=_demo)


def _add_free_motion(ssub: argparse._SubParsersAction) -> None:
    """``simulate free-motion``."""
    fm = ssub.add_parser("free-motion", help="false-alarm check: the demo trajectory without obstacle")
    add_common(fm, default_out="results/free-motion")
    add_model_options(fm)
    add_robot_options(fm)
    add_output_options(fm)
    fm.add_argument("--duration", type=float, default=60.0, help="simulated time [s] (default 60)")
    fm.add_argument("--threshold", type=float, default=11.0, help="zeta [Nm] (default 11)")
    fm.add_argument(
        "--trace",
        default="auto",
        metavar="FILE.parquet|none",
        help="stream the trace to this Parquet file, block by block (default: free_motion_trace.parquet in --out: "
        "every tick up to 600 s, ~0.41 MB per simulated second of the Atlas arm, every 100th tick beyond, ~20 MB "
        "per simulated hour; 'none': statistics only; memory does not grow with --duration either way)",
    )
    fm.add_argument(
        "--trace-every",
        type=int,
        default=None,
        metavar="TICKS",
        help="write every TICKS-th tick to the trace (default: 1 up to 600 s, 100 beyond); the statistics are "
        "over every tick whatever this is",
    )
    fm.add_argument(
        "--motion",
        choices=("demo", "loaded", "hydraulic"),
        default="demo",
        help="demo: the demo's swing (shz on Atlas); loaded: the four joints with the largest gravity and friction "
        "load move together (on Atlas the hydraulic ones; 'hydraulic' is its Atlas-only alias) (default demo)",
    )
    fm.set_defaults(func=_free)


def _add_velocity_tracking(ssub: argparse._SubParsersAction) -> None:
    """``simulate velocity-tracking``."""
    vt = ssub.add_parser(
        "velocity-tracking",
        help="constant-velocity run of one joint: PD position control vs impedance control (2) (Fig. 5)",
    )
    add_common(vt, default_out="results/velocity-tracking")
    add_model_options(vt)
    add_robot_options(vt)
    add_output_options(vt)
    vt.add_argument(
        "--joint",
        type=int,
        default=None,
        help="moving joint, 1-based (default 4 on Atlas: elx, as in Fig. 5; other arms joint ceil(n/2))",
    )
    vt.add_argument(
        "--speed", type=float, default=None, help="constant speed [rad/s] (default 0.3; at most half the joint's limit)"
    )
    vt.add_argument(
        "--travel", type=float, default=None, help="travel of each leg [rad] (default 0.9; within the joint's range)"
    )
    vt.add_argument(
        "--pd-kp",
        type=float,
        default=None,
        help="PD: K_p of the moving joint [Nm/rad] (default Atlas 1000 hydraulic, 100 wrist; other arms "
        "M_jj (56 rad/s)^2)",
    )
    vt.add_argument(
        "--pd-kd",
        type=float,
        default=None,
        help="PD: K_d of the moving joint [Nms/rad] (default Atlas 30 hydraulic, 3 wrist; other arms "
        "2 0.8 (56 rad/s) M_jj)",
    )
    vt.add_argument("--stiffness", type=float, default=300.0, help="impedance: k_i [Nm/rad] (default 300)")
    vt.set_defaults(func=_velocity)


def _event_row(row: dict[str, Any], trace: Any, robot: Any) -> dict[str, Any]:
    """``row`` with the run's collision event (:func:`~reflexarm.experiments.collision_events.collision_outcome`)
    under "event" and the printed event columns."""
    from reflexarm.experiments.collision_events import collision_outcome

    event = collision_outcome(trace, robot, name=str(row.get("run", "run"))).as_dict()
    return {
        **row,
        "event": event,
        "ke_ratio": event["kinetic_energy_ratio"],
        "moved_m": event["moved_after_detection_m"],
        "recontact": None if event["detected_s"] is None else ("yes" if event["recontact"] else "no"),
    }


def _print_detection(detection: DetectionChoice, plant_friction: str) -> None:
    note = tuned_gain_note(detection, 5.0)
    if note:
        print(note, file=sys.stderr)
    if plant_friction == "none":
        print("true arm: no joint friction or damping (--plant-friction none)", file=sys.stderr)


def _demo(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import (
        EE_SETTINGS,
        compare_with_paper,
        run_ee_collision,
        summarize_ee_collision,
    )
    from reflexarm.experiments.plots import plot_fig8

    choice = model_choice(args)
    robot = load_robot_from_args(args)
    detection = detection_choice(args, robot)
    model = choice.build(robot)
    out = out_dir(args)
    print(f"controller model: {choice.label()}; sensor noise: the paper's; cinderblock: {args.block}", file=sys.stderr)
    print(model_error_line(robot, model), file=sys.stderr)
    _print_detection(detection, args.plant_friction)
    traces, rows = [], []
    scene = SceneCapture(args, out, "ee_collision")
    settings = [with_detection(s, detection) for s in EE_SETTINGS]
    for setting in settings:
        print(setting_line(setting), file=sys.stderr)
        with scene:
            tr = run_ee_collision(
                setting,
                model=model,
                model_error=0.0,
                block=args.block,
                seed=args.seed,
                progress=not args.quiet,
                robot=robot,
                depth=args.depth,
                plant_friction=args.plant_friction,
            )
        tr.meta["controller_model"] = choice.describe()
        traces.append(tr)
        rows.append(_event_row(number_joints(summarize_ee_collision(tr), robot.joint_names), tr, robot))
        rows[-1]["controller_fault"] = fault_record(tr)
        if setting.threshold is not None:
            rows[-1]["detection"] = tr.meta["detection"] = detection.describe()
    runs = [s.name for s in settings]  # one name per run for the traces and the videos (run_outputs.slug)
    write_traces(out, "ee_collision", dict(zip(runs, traces, strict=True)))
    write_json(out / "ee_collision_summary.json", rows)
    _print_placement(traces[0].meta.get("placement"))
    pictures = scene.finish(runs, summary=out / "ee_collision_summary.json")
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
                ("final_swing_error_rad", f"|q{rows[0].get('swing_joint', 1)} err| end [rad]", "{:.3f}"),
                *_EVENT_COLUMNS,
            ],
        )
    )
    for r in rows:
        if r["controller_fault"] is not None:
            print(fault_line(r["run"], r["controller_fault"]))
        if r["first_contact_s"] is None and r.get("first_contact_any_s") is not None:
            print(
                f"[{r['run']}] contact on links before the wrist sensor from t = {r['first_contact_any_s']:.3f} s "
                f"(peak external joint torque {r['peak_external_torque_Nm']:.1f} Nm); the forces above count only "
                "the bodies beyond the sensor"
            )
    print("\nthe paper (Sec. III-A, Figs. 7-8) beside this run:")
    print(format_table(compare_with_paper(rows), _PAPER_COLUMNS))
    print(f"\nwrote {out}/ (traces *.npz, ee_collision_summary.json, {fig.name})")
    print(SceneCapture.describe(pictures))
    return 0


def _print_placement(placement: dict[str, Any] | None) -> None:
    """Where the scene placed itself on an arm other than Atlas (stored in each trace's meta too)."""
    if not placement:
        return
    p = placement
    if "position" in p:
        x, y = p["position"]
        core = tuple(round(float(v), 3) for v in p["size"])
        print(
            f"scene placed from the arm's kinematics: joint {p['swing_joint']} swings the end effector in "
            f"{p['move_time_s']:.1f} s; cinderblock at ({x:.3f}, {y:.3f}) m, yaw {p['yaw']:.2f} rad, core {core} m, "
            f"table {p['table_height']:.3f} m high; the unobstructed path would run {p['depth']:g} m into it from "
            f"t = {p['contact_time_s']:.2f} s",
            file=sys.stderr,
        )
    else:
        print(
            f"scene placed from the arm's kinematics: the stick pushes link {p['link']} ({p['body']}) while joint "
            f"{p['swing_joint']} swings it in {p['move_time_s']:.1f} s",
            file=sys.stderr,
        )


def _link(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import (
        LINK_SETTING,
        compare_with_paper,
        model_torque,
        run_link_collision,
        summarize_link_collision,
    )
    from reflexarm.experiments.plots import plot_fig10

    choice = model_choice(args)
    robot = load_robot_from_args(args)
    detection = detection_choice(args, robot)
    model = choice.build(robot)
    print(f"controller model: {choice.label()}; sensor noise: the paper's", file=sys.stderr)
    print(model_error_line(robot, model), file=sys.stderr)
    _print_detection(detection, args.plant_friction)
    setting = with_detection(LINK_SETTING, detection)
    print(setting_line(setting), file=sys.stderr)
    out = out_dir(args)
    with SceneCapture(args, out, "link_collision") as scene:
        tr = run_link_collision(
            model=model,
            model_error=0.0,
            setting=setting,
            seed=args.seed,
            progress=not args.quiet,
            robot=robot,
            link=args.link,
            plant_friction=args.plant_friction,
            stick=args.stick,
        )
    tr.meta["controller_model"] = choice.describe()
    tr.meta["detection"] = detection.describe()
    row = _event_row(number_joints(summarize_link_collision(tr), robot.joint_names), tr, robot)
    row["detection"] = detection.describe()
    row["controller_fault"] = fault_record(tr)
    write_traces(out, "link_collision", {"link collision": tr})
    write_json(out / "link_collision_summary.json", [row])
    _print_placement(tr.meta.get("placement"))
    pictures = scene.finish(["link collision"], summary=out / "link_collision_summary.json")
    # tau_mdl of Fig. 10 is the controller's model torque
    fig = plot_fig10(tr, model_torque(tr, model), out / "fig10_link_collision.png")
    print(
        format_table(
            [row],
            [
                ("contact_start_s", "contact [s]", "{:.3f}"),
                ("detection_s", "detected [s]", "{:.3f}"),
                ("detection_delay_s", "delay [s]", "{:.3f}"),
                ("detected_joints", "joints", "{}"),
                ("peak_external_torque_Nm", "peak |tau_ext| [Nm]", "{:.1f}"),
                *_EVENT_COLUMNS,
            ],
        )
    )
    if row["controller_fault"] is not None:
        print(fault_line("link collision", row["controller_fault"]))
    print("\nthe paper (Sec. III-B, Figs. 9-10) beside this run:")
    print(format_table(compare_with_paper([], row), _PAPER_COLUMNS))
    print(f"\nwrote {out}/ (trace, link_collision_summary.json, {fig.name})")
    print(SceneCapture.describe(pictures))
    return 0


def _free(args: argparse.Namespace) -> int:
    from reflexarm.experiments.collision import free_motion_false_alarms

    out = out_dir(args)
    choice = model_choice(args)
    robot = load_robot_from_args(args)
    trace_path = {"auto": str(out / "free_motion_trace.parquet"), "none": None}.get(args.trace, args.trace)
    scene = SceneCapture(args, out, "free_motion")
    with scene:
        res = free_motion_false_alarms(
            args.duration,
            threshold=args.threshold,
            seed=args.seed,
            progress=not args.quiet,
            model_error=choice.level,
            model_seed=choice.seed,
            model=None if choice.file is None else choice.build(robot),
            motion=args.motion,
            trace_path=trace_path,
            robot=robot,
            trace_every=args.trace_every,
        )
    res["controller_model"] = choice.describe()  # type: ignore[assignment]
    # the smallest zeta without a false alarm over this run is the largest |residual| of any joint
    res["smallest_alarm_free_threshold_Nm"] = max(res["max_abs_residual_Nm"])  # type: ignore[call-overload]
    write_json(out / "free_motion.json", res)
    from reflexarm.experiments.plots import plot_free_motion

    fig = plot_free_motion(res, robot.joint_names, args.threshold, out / "free_motion.png", trace_path)
    pictures = scene.finish(["free motion"], summary=out / "free_motion.json")
    print(json.dumps(res, indent=2))
    if res["fault_ticks"]:
        print(
            f"the controller FAULTED on {res['fault_ticks']} of the run's ticks (the trace's 'fault' column says why): "
            "those ticks are the fault's safe command, not free motion"
        )
    print(f"wrote {out}/ (free_motion.json, {fig.name}{', ' + Path(trace_path).name if trace_path else ''})")
    print(SceneCapture.describe(pictures))
    return 0


def _velocity(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from reflexarm.errors import ConfigError
    from reflexarm.experiments.velocity_tracking import (
        VelocityTrackingSetup,
        plot_velocity_tracking,
        run_velocity_tracking,
    )

    robot = load_robot_from_args(args)
    if args.joint is not None and not 1 <= args.joint <= robot.n:
        raise ConfigError(f"--joint must be in 1..{robot.n}; got {args.joint}")
    base = VelocityTrackingSetup.for_robot(robot, None if args.joint is None else args.joint - 1)
    j = base.joint
    kp, kd = list(base.pd_kp), list(base.pd_kd)
    if args.pd_kp is not None:
        kp[j] = args.pd_kp
    if args.pd_kd is not None:
        kd[j] = args.pd_kd
    setup = replace(
        base,
        speed=base.speed if args.speed is None else args.speed,
        travel=base.travel if args.travel is None else args.travel,
        pd_kp=tuple(kp),
        pd_kd=tuple(kd),
        stiffness=args.stiffness,
    )
    choice = model_choice(args)
    print(
        f"joint {j + 1} at {setup.speed:g} rad/s on the dry-friction plant (the robot file's friction), paper noise; "
        f"controller model: {choice.label()}\n"
        f"PD: K_p = {kp[j]:g} Nm/rad, K_d = {kd[j]:g} Nms/rad, gravity feed-forward; "
        f"impedance (2): k = {args.stiffness:g} Nm/rad, d_xi = {setup.damping_ratio:g}",
        file=sys.stderr,
    )
    model = choice.build(robot)
    print(model_error_line(robot, model), file=sys.stderr)
    out = out_dir(args)
    with SceneCapture(args, out, "velocity_tracking") as scene:
        res = run_velocity_tracking(setup, model=model, seed=args.seed, progress=not args.quiet, robot=robot)
    for tr in res.traces.values():
        tr.meta["controller_model"] = choice.describe()
    write_traces(out, "velocity_tracking", res.traces)
    doc = res.as_dict()
    doc["controller_model"] = choice.describe()
    doc["setup"] = {**doc["setup"], "joint": j + 1, "joint_name": robot.joint_names[j]}  # 1-based, as --joint
    (out / "velocity_tracking_summary.json").write_text(json.dumps(doc, indent=2))
    fig = plot_velocity_tracking(res, out / "fig5_velocity_tracking.png")
    pictures = scene.finish(list(res.traces), summary=out / "velocity_tracking_summary.json")
    print(
        format_table(
            res.rows(),
            [
                ("controller", "controller", "{}"),
                ("rms_dq_error", "RMS dq err, constant speed [rad/s]", "{:.4f}"),
                ("max_dq_error", "max |dq err|, constant speed [rad/s]", "{:.4f}"),
                ("rms_dq_error_all", "RMS dq err, whole run [rad/s]", "{:.4f}"),
            ],
        )
    )
    print(f"\nwrote {out}/ (traces *.npz, velocity_tracking_summary.json, {fig.name})")
    print(SceneCapture.describe(pictures))
    return 0
