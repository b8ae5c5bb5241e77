"""``reflexarm pfl``: human contact limits (ISO/TS 15066 power and force limiting) for an arm, a motion and each
reaction: permissible speeds from the standard's mass and the arm's posture-dependent mass, simulated contacts
with body regions, clamping; or the check of your own trajectory file, sample by sample."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from reflexarm.errors import ConfigError

#: Written here so that building the parser imports no experiment (the study's own constants are the same).
PFL_ARMS = ("panda", "iiwa14", "ur_like", "atlas_v5_left_arm")
PFL_REGIONS = ("chest", "abdomen", "hand", "upper_arm", "skull")
PFL_REACTIONS = ("none", "gravity", "brake", "retract", "compliant")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``pfl`` to the top-level parser."""
    p = sub.add_parser(
        "pfl",
        help="human contact limits (ISO/TS 15066): permissible speeds, simulated contacts per body region, clamping",
        description="Swing each arm's end effector (and the links of --points) into ISO/TS 15066 body regions at "
        "several speeds (detection off and each reaction), clamp the region against a wall, and compare with "
        "v sqrt(mu k); or simulate your own motion (--trajectory, time-scaled to each speed) and check it sample "
        "by sample. Writes pfl_runs.csv, pfl_table.csv, pfl.json, pfl_<region>.png, "
        "pfl_report.html.",
    )
    p.add_argument("--arms", default=",".join(PFL_ARMS), metavar="LIST", help=f"arms (default {','.join(PFL_ARMS)})")
    p.add_argument(
        "--regions",
        default=",".join(PFL_REGIONS),
        metavar="LIST",
        help=f"body regions (default {','.join(PFL_REGIONS)})",
    )
    p.add_argument("--speeds", default="0.25,0.5,0.75", metavar="LIST", help="peak end-effector speeds [m/s]")
    p.add_argument(
        "--reactions", default=",".join(PFL_REACTIONS), metavar="LIST", help="reactions after detection (default all)"
    )
    p.add_argument("--clamp-speed", type=float, default=0.25, help="speed of the clamping runs [m/s] (default 0.25)")
    p.add_argument(
        "--clamp-stiffness",
        type=float,
        default=300.0,
        help="joint stiffness of the clamping runs [Nm/rad] (default 300)",
    )
    p.add_argument("--stiffness", type=float, default=100.0, help="joint stiffness of the transient runs [Nm/rad]")
    p.add_argument("--observer-gain", type=float, default=5.0, help="observer gain k_o [1/s] (default 5)")
    p.add_argument("--model-error", type=float, default=10.0, metavar="PCT", help="controller model error [%%]")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise and the model errors (default 0)")
    p.add_argument(
        "--points",
        default="ee",
        metavar="LIST",
        help="contact points per arm: ee and/or link1..link<n> (the link joint j moves; the point along it with the "
        "largest speed along the motion) (default ee)",
    )
    p.add_argument(
        "--trajectory",
        type=Path,
        default=None,
        metavar="CSV",
        help="simulate this motion instead of the demo swing (of the first arm of --arms): columns t, then one per "
        "joint [rad], or the t, position_<joint>..., velocity_<joint>... of 'reflexarm excite --csv'; the region "
        "where each point of --points moves fastest, the motion at its own timing and time-scaled (same path) so "
        "that the point's speed there is each of --speeds; also checked sample by sample (pfl_trajectory.json)",
    )
    p.add_argument(
        "--check-only",
        action="store_true",
        help="with --trajectory: only the sample-by-sample check against the permissible speeds (no simulation)",
    )
    p.add_argument("--out", type=Path, default=Path("results/pfl"), help="output folder (default results/pfl)")
    p.set_defaults(func=_pfl)


def _names(text: str, flag: str, choices: tuple[str, ...] | None) -> list[str]:
    names = list(dict.fromkeys(x.strip() for x in str(text).split(",") if x.strip()))
    if not names:
        raise ConfigError(f"{flag} needs at least one name; got {text!r}")
    bad = [x for x in names if choices is not None and x not in choices]
    if bad:
        raise ConfigError(f"{flag}: unknown {bad[0]!r}; choose from: {', '.join(choices or ())}")
    return names


def _speeds(text: str) -> list[float]:
    try:
        v = [float(x) for x in str(text).split(",") if x.strip()]
    except ValueError as e:
        raise ConfigError(f"--speeds must be comma-separated speeds [m/s]; got {text!r}") from e
    if not v or any(not (math.isfinite(x) and x > 0.0) for x in v):
        raise ConfigError(f"--speeds must be positive speeds [m/s]; got {text!r}")
    return sorted(v)


def _check_trajectory(args: argparse.Namespace, arm: str, regions: list[str], motion: Any, robot: Any) -> None:
    """The sample-by-sample check of the motion at its own timing (``pfl_trajectory.json``)."""
    import json

    from reflexarm.safety import check_trajectory_speed

    t = motion.t
    q, dq, _ = motion.at_file_time(t)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"robot": arm, "file": str(args.trajectory), "regions": {}}
    for region in regions:
        check = check_trajectory_speed(robot, t, q, dq, region)
        s = check.summary()
        report["regions"][region] = {**s, "violations": check.violations()}
        print(
            f"{region}: {s['samples_over_limit']}/{s['samples']} samples over the limit; worst {s['worst_point']} at "
            f"t = {s['worst_t_s']:.3f} s: {s['worst_speed_m_s']:.3f} m/s vs permissible "
            f"{s['worst_permissible_speed_m_s']:.3f} m/s (standard M/2: {s['standard_permissible_speed_m_s']:.3f} m/s)"
        )
    (out / "pfl_trajectory.json").write_text(json.dumps(report, indent=1))
    print(f"wrote {out / 'pfl_trajectory.json'}", file=sys.stderr)


def _points(text: str, robots: list[tuple[str, Any]]) -> list[str]:
    from reflexarm.experiments.pfl_placement import point_names

    points = _names(text, "--points", None)
    for arm, robot in robots:
        valid = point_names(robot)
        bad = [p for p in points if p not in valid]
        if bad:
            raise ConfigError(f"--points: {arm} has no contact point {bad[0]!r}; choose from: {', '.join(valid)}")
    return points


def _pfl(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from reflexarm.experiments.pfl import PFL_SETTING
    from reflexarm.experiments.pfl_report import speed_table, write_pfl_outputs
    from reflexarm.experiments.pfl_study import run_pfl_motion_study, run_pfl_study
    from reflexarm.experiments.reaction_study import study_arm
    from reflexarm.safety import region_names

    arms = _names(args.arms, "--arms", PFL_ARMS)
    regions = _names(args.regions, "--regions", region_names())
    reactions = _names(args.reactions, "--reactions", PFL_REACTIONS)
    speeds = _speeds(args.speeds)
    if not 0.0 <= args.model_error < 100.0:
        raise ConfigError(f"--model-error must be a percentage in [0, 100); got {args.model_error:g}")
    robots = [(a, study_arm(a).robot) for a in (arms[:1] if args.trajectory is not None else arms)]
    points = _points(args.points, robots)
    setting = replace(PFL_SETTING, stiffness=args.stiffness, observer_gain=args.observer_gain)
    t0 = time.perf_counter()
    common: dict[str, Any] = dict(
        setting=setting,
        model_error=args.model_error / 100.0,
        seed=args.seed,
        progress=lambda m: print(f"[{time.perf_counter() - t0:6.1f} s] {m}", file=sys.stderr, flush=True),
    )
    if args.trajectory is not None:
        from reflexarm.experiments.pfl_motion import read_motion_csv

        arm, robot = robots[0]
        motion = read_motion_csv(args.trajectory, robot)
        _check_trajectory(args, arm, regions, motion, robot)
        if args.check_only:
            return 0
        print(f"{arm}: simulating {motion.name} at its own timing and time-scaled to each of --speeds", file=sys.stderr)
        study = run_pfl_motion_study(arm, robot, motion, regions, speeds, reactions, points, **common)
    else:
        study = run_pfl_study(
            robots, regions, speeds, reactions, clamp_speed=args.clamp_speed, clamp_stiffness=args.clamp_stiffness,
            points=points, **common,
        )  # fmt: skip
    paths = write_pfl_outputs(study, args.out)
    for row in speed_table(study):
        flag = " (extrapolated: that speed could not be simulated, see errors)" if row["v_sim_extrapolated"] else ""
        print(
            f"{row['arm']:>18} {row['contact_point']:>6} {row['region']:>9}: v_max standard "
            f"{_f(row['v_standard_m_s'])} m/s, posture {_f(row['v_posture_m_s'])} m/s, simulated (detection off) "
            f"{_f(row['v_sim_detection_off_m_s'])} m/s{flag}; max simulated/analytic peak "
            f"{_f(row['sim_over_analytic_max'])}"
        )
    print(f"wrote {', '.join(str(p) for p in paths.values())}", file=sys.stderr)
    return 0


def _f(v: Any) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"
