"""``reflexarm identify payload`` and ``reflexarm identify friction --log`` (friction from ordinary motion).

Both work on logs of ordinary motion with the arm's model known or (friction, ``combined``) not needed:
:mod:`reflexarm.ident.payload` and :mod:`reflexarm.ident.friction.from_motion`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from reflexarm._cli.common import add_common, format_table, out_dir
from reflexarm._cli.ident_common import friction_file, load_robot_arg, robot_args, say, write_csv, write_json
from reflexarm._cli.log_options import add_log_options, load_log_from_args
from reflexarm.errors import ConfigError


def add_friction_from_motion_options(f: argparse.ArgumentParser) -> None:
    """The options of ``identify friction`` for logs of ordinary motion."""
    f.add_argument(
        "--log",
        action="append",
        default=[],
        metavar="LOG",
        help="a log of ordinary motion (no constant-velocity runs needed); repeatable: friction of every joint that "
        "moves enough, by --motion-method",
    )
    f.add_argument(
        "--motion-method",
        choices=("combined", "steady"),
        default="combined",
        help="with --log: 'combined' (default; the friction columns of the combined regression, no model needed) or "
        "'steady' (fit on the steadily moving samples with the rigid-body torque of --model, or of the robot file, "
        "removed: only as good as that model)",
    )
    f.add_argument("--model", default=None, help="with --log: model.json whose rigid-body torque 'steady' removes")
    f.add_argument("--cutoff", type=float, default=10.0, help="with --log: low-pass cutoff [Hz] (default 10)")


def friction_from_motion_command(args: argparse.Namespace) -> int:
    """``identify friction --log LOG...``: friction.json from ordinary motion, the method named."""
    from reflexarm.ident import preprocess_log
    from reflexarm.ident.friction.from_motion import identify_friction_from_motion

    out = out_dir(args)
    robot = load_robot_arg(args)
    logs = [preprocess_log(load_log_from_args(args, p, robot), cutoff_hz=args.cutoff) for p in args.log]
    model = _model(args, robot)
    say(args, f"friction from ordinary motion ({args.motion_method}) on {len(logs)} log(s) ...")
    res = identify_friction_from_motion(
        robot, logs, method=args.motion_method, model=model, offset=not args.no_offset, filter_cutoff_hz=args.cutoff
    )
    print(res.describe(robot.joint_names))
    rows: list[dict[str, object]] = []
    for j in range(robot.n):
        known = j not in res.not_identified
        rows.append(
            {
                "joint": f"{j + 1} ({robot.joint_names[j]})",
                "mu_C": float(res.friction.coulomb[j]) if known else None,
                "mu_C_std": float(res.std.coulomb[j]) if known else None,
                "d_v": float(res.friction.viscous[j]) if known else None,
                "d_v_std": float(res.std.viscous[j]) if known else None,
                "offset": None if res.friction.offset is None or not known else float(res.friction.offset[j]),
                "samples": int(res.samples[j]),
                "speed_p95": float(res.speed_range[j]),
                "method": res.method,
            }
        )
    write_csv(out / "friction.csv", rows)
    doc = friction_file(robot, res.friction, rows, "did not move enough in the logs (see 'why')")
    doc["method"] = f"from ordinary motion: {res.method}"
    doc["notes"] = list(res.notes)
    doc["why"] = {str(j + 1): why for j, why in res.not_identified.items()}
    write_json(out / "friction.json", doc)
    print(
        format_table(
            rows,
            [
                ("joint", "joint", "{}"),
                ("mu_C", "mu_C [Nm]", "{:.3f}"),
                ("mu_C_std", "+-", "{:.3f}"),
                ("d_v", "d_v [Nms/rad]", "{:.3f}"),
                ("d_v_std", "+-", "{:.3f}"),
                ("speed_p95", "|dq| p95 [rad/s]", "{:.2f}"),
            ],
        )
    )
    for note in res.notes:
        print(note)
    print(
        "+-: the fit's standard errors; they do not hold the bias of slow motion (d_v off by 20-80 % on simulated "
        "joints peaking below ~1 rad/s, see reflexarm.ident.friction.from_motion): log fast motion of every joint"
    )
    print(f"\nwrote {out}/ (friction.json, friction.csv): 'identify dynamics --friction {out}/friction.json'")
    return 0


def _model(args: argparse.Namespace, robot: Any) -> Any:
    if args.model is None:
        return None
    from reflexarm.ident import load_identified_model

    return load_identified_model(args.model, robot)


def register_payload(isub: argparse._SubParsersAction) -> None:
    """Add ``identify payload``."""
    p = isub.add_parser(
        "payload",
        help="mass and COM of a load at the tool from a log, the arm's model known; and whether the load changed "
        "during the log",
    )
    p.add_argument("log_path", metavar="LOG", help="a log of motion with the load (.csv/.parquet/.npz or a bag)")
    robot_args(p)
    p.add_argument("--model", default=None, help="model.json of the arm without the load (default: the robot file)")
    p.add_argument("--inertia", action="store_true", help="identify the load's inertia too (10 parameters, not 4)")
    p.add_argument("--cutoff", type=float, default=10.0, help="low-pass cutoff [Hz] (default 10)")
    p.add_argument(
        "--write-model",
        default=None,
        metavar="OUT",
        help="with --model: also write a copy of that model file with the payload added to the last link (loads like "
        "any model file: 'validate --model OUT', 'detect --model OUT')",
    )
    add_log_options(p)
    add_common(p, default_out="results/payload")
    p.set_defaults(func=payload_command)


def payload_command(args: argparse.Namespace) -> int:
    """``identify payload LOG``: payload.json, and the change check."""
    from reflexarm.errors import IdentificationError
    from reflexarm.ident import preprocess_log
    from reflexarm.ident.payload import detect_payload_change, identify_payload

    if args.write_model is not None and args.model is None:
        raise ConfigError("--write-model needs --model (the model file the payload is added to)")
    out = out_dir(args)
    robot = load_robot_arg(args)
    model = _model(args, robot)
    log = preprocess_log(load_log_from_args(args, args.log_path, robot), cutoff_hz=args.cutoff)
    payload = identify_payload(robot, log, model=model, inertia=args.inertia)
    print(payload.describe())
    try:
        change = detect_payload_change(robot, log, model=model)
        change_doc: dict[str, object] = change.to_dict()
        print(change.reason)
        if change.changed:  # the whole-log payload mixes two loads: the one after the change is what is carried now
            print("the payload above averages the loads before and after the change; after it:")
            payload = identify_payload(robot, log.select(log.t >= change.time), model=model, inertia=args.inertia)
            print(payload.describe())
            change_doc["payload_is_after_the_change"] = True
    except IdentificationError as e:  # too short for two segments: the payload still stands
        change_doc = {"changed": None, "reason": str(e)}
        print(f"change of load not checked: {e}")
    written = ["payload.json"]
    if args.write_model is not None:
        from reflexarm.ident.payload import write_model_with_payload

        written.append(str(write_model_with_payload(args.model, payload, Path(args.write_model))))
    write_json(
        out / "payload.json",
        {"robot": robot.name, "log": str(args.log_path), "payload": payload.to_dict(), "change": change_doc},
    )
    print(f"\nwrote {out}/ ({', '.join(written)})")
    return 0


__all__ = ["add_friction_from_motion_options", "friction_from_motion_command", "register_payload"]
