"""``reflexarm isolation-study``: isolation and identification over seeded random contacts (issue 15)."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``isolation-study`` to the top-level parser."""
    from reflexarm._cli.robot_options import add_robot_options

    p = sub.add_parser(
        "isolation-study",
        help="which link, where, how hard: isolation and identification over seeded random contacts",
    )
    add_robot_options(p)
    p.add_argument("--contacts", type=int, default=1000, help="random contacts per variant (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the contacts, noise and model errors (default 0)")
    p.add_argument("--noise", action="store_true", help="also run with the paper's sensor noise on the residual")
    p.add_argument(
        "--model-error",
        type=float,
        default=0.0,
        metavar="PCT",
        help="also run with +-PCT %% model errors (masses, COMs, inertias; e.g. 10)",
    )
    p.add_argument("--spacing", type=float, default=0.01, help="candidate point spacing [m] (default 0.01)")
    p.add_argument(
        "--contact-friction",
        type=float,
        default=0.5,
        help="friction coefficient of the true forces' cone (default 0.5; inf: any direction into the surface)",
    )
    p.add_argument("--out", default="out/isolation", help="output folder (default out/isolation)")
    p.set_defaults(func=_isolation_study)


def _isolation_study(args: argparse.Namespace) -> int:
    from reflexarm._cli.robot_options import load_robot_from_args
    from reflexarm.experiments.isolation_study import run_isolation_study, write_isolation_study
    from reflexarm.robots.collision_geometry import link_collision_geometry

    robot = load_robot_from_args(args)
    geometry = link_collision_geometry(robot, spacing=args.spacing)
    common: dict[str, Any] = dict(contacts=args.contacts, seed=args.seed, spacing=args.spacing, geometry=geometry)
    studies = [run_isolation_study(robot, contact_friction=args.contact_friction, **common)]
    if args.noise or args.model_error:
        studies.append(
            run_isolation_study(
                robot,
                noise=args.noise,
                model_error=args.model_error / 100.0,
                contact_friction=args.contact_friction,
                **common,
            )
        )
    print(f"isolation study: {robot.name}, {args.contacts} contacts per variant, seed {args.seed}")
    if len(studies) > 1:  # what "noisy" holds: the noise, the model error or both
        parts = (["the paper's sensor noise"] if args.noise else []) + (
            [f"+-{args.model_error:g} % model error"] if args.model_error else []
        )
        print(f"  noisy: {' and '.join(parts)}")
    for s in studies:
        sm = s.summary
        rate = sm["correct_link_rate"]
        print(
            f"  {s.variant:6s} sensed {sm['sensed']}/{sm['contacts']}  correct link "
            f"{'-' if rate is None else f'{100 * rate:.1f} %'}  (wrong: {sm['wrong_link']}, of which a more proximal "
            f"link explains the residual: {sm['wrong_more_proximal_explained']}, own joint below its level: "
            f"{sm['wrong_axis_crossing']})"
        )
        ls = sm["correct_link_rate_link_sensed"]
        print(
            f"         link sensed (own joint above its level) {sm['link_sensed']}: correct link "
            f"{'-' if ls is None else f'{100 * ls:.1f} %'}; own joint below its level {sm['link_not_sensed']}: "
            f"true link among the candidate links {sm['link_not_sensed_true_in_candidates']}"
        )
        pe, fe, de = sm["point_error_m"], sm["force_error_pct"], sm["direction_error_deg"]
        if pe["count"]:
            print(
                f"         point error median {100 * pe['median']:.2f} cm, 90 % {100 * pe['p90']:.2f} cm "
                f"(n={pe['count']}); "
                f"force error median {fe['median']:.2f} %, 90 % {fe['p90']:.2f} %; "
                f"direction median {de['median']:.2f} deg, 90 % {de['p90']:.2f} deg"
            )
        print(f"         {'link':24s} {'n':>5s} {'correct':>8s}  determined (point_and_force/force_only/link_only)")
        for name, b in sm["per_link"].items():
            r = b["correct_link_rate"]
            d = b["determined"]
            print(
                f"         {name:24s} {b['contacts']:5d} {'-' if r is None else f'{100 * r:.1f} %':>8s}  "
                f"{d['point_and_force']}/{d['force_only']}/{d['link_only']}"
            )
    for path in write_isolation_study(studies, args.out):
        print(f"wrote {path}")
    return 0
