"""``reflexarm reaction-study``: what each reaction leaves the arm doing after a detected collision (issue 15)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from reflexarm._cli.common import add_reaction_setting_option
from reflexarm.errors import ConfigError

#: The printed table: (key of :func:`~reflexarm.experiments.reaction_study.reaction_measures` or of the row,
#: header, format).
COLUMNS = (
    ("arm", "arm", "{}"),
    ("scenario", "scenario", "{}"),
    ("reaction", "reaction", "{}"),
    ("level_text", "at detection -> peak after", "{}"),
    ("ke_ratio", "KE(+0.5 s)/KE(det)", "{:.3g}"),
    ("kinetic_energy_after_J", "KE(+0.5 s) [J]", "{:.2g}"),
    ("rest_floor_q95_J", "rest floor [J]", "{:.2g}"),
    ("moved_m", "moved [m]", "{:.3f}"),
    ("away_m", "away at end [m]", "{:.3f}"),
    ("peak_speed_ratio", "peak speed/limit", "{:.2f}"),
    ("recontact", "re-contact", "{}"),
    ("guard", "guard", "{}"),
)
#: Longest guard text printed in the table (the whole text is in the JSON and CSV).
GUARD_WIDTH = 60


#: The defaults of reflexarm.experiments.reaction_study (STUDY_ARMS, STUDY_REACTIONS, SCENARIOS), written here so
#: that building the parser imports no experiment (tests/test_reaction_study_cli.py checks they agree).
STUDY_ARMS = ("atlas_v5_left_arm", "panda", "iiwa14", "ur_like", "iiwa14_frictionless")
STUDY_REACTIONS = ("gravity", "brake", "retract", "compliant")
SCENARIOS = ("demo", "link", "link_held")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``reaction-study`` to the top-level parser."""
    p = sub.add_parser(
        "reaction-study",
        help="each reaction to a detected collision on several arms: energy, force, motion, re-contact, guard",
        description="Run the demo contact and the link push with each reaction on each arm (truth from the plant) "
        "and print what the arm did after detection; writes reaction_study.csv/.json and reaction_study.png.",
    )
    p.add_argument(
        "--arms",
        default=",".join(STUDY_ARMS),
        metavar="LIST",
        help=f"comma-separated arms (default all: {','.join(STUDY_ARMS)})",
    )
    p.add_argument(
        "--reactions",
        default=",".join(STUDY_REACTIONS),
        metavar="LIST",
        help=f"comma-separated reactions (default {','.join(STUDY_REACTIONS)}; 'none' adds the report-only baseline)",
    )
    p.add_argument(
        "--scenarios",
        default=",".join(SCENARIOS),
        metavar="LIST",
        help="comma-separated scenarios: demo (end-effector contact), link (the paper's link push: the stick keeps "
        "coming), link_held (the link runs into a held stick) "
        f"(default {','.join(SCENARIOS)})",
    )
    p.add_argument(
        "--model-error",
        type=float,
        default=10.0,
        metavar="PCT",
        help="the controller's model error, +-PCT %% on masses, COMs, inertias and friction (default 10)",
    )
    p.add_argument(
        "--noise",
        choices=("paper", "none"),
        default="paper",
        help="sensor noise: the paper's (default) or none (what the reactions do without it)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise and the model errors (default 0)")
    p.add_argument(
        "--detection-study",
        type=Path,
        default=None,
        metavar="JSON",
        help="detect with the (k_o, zeta) pairs a 'reflexarm detection-study' tuned per arm (its "
        "detection_study.json or the folder it wrote): each arm's detection observer (exact form) and per-joint "
        "levels, on the model errors they were tuned on (default: the paper's k_o = 5 1/s, 11 Nm)",
    )
    p.add_argument(
        "--detection-gain",
        default="auto",
        metavar="K_O|auto",
        help="with --detection-study: the detection gain [1/s] of every arm, or auto: each arm's smallest gain "
        "whose ramp lag is within 10 ms and whose held-out hour had no false alarm (default auto)",
    )
    add_reaction_setting_option(p)
    p.add_argument(
        "--out",
        type=Path,
        default=Path("results/reaction-study"),
        help="output folder (default results/reaction-study)",
    )
    p.set_defaults(func=_reaction_study)


def _names(text: str, flag: str, choices: tuple[str, ...] | None) -> list[str]:
    """``"a,b"`` -> ["a", "b"]; an empty list or a name outside ``choices`` is a :class:`ConfigError`."""
    names = [x.strip() for x in str(text).split(",") if x.strip()]
    if not names:
        hint = f"; choose from: {', '.join(choices)}" if choices else ""
        raise ConfigError(f"{flag} needs at least one name; got {text!r}{hint}")
    if choices is not None:
        bad = [x for x in names if x not in choices]
        if bad:
            raise ConfigError(f"{flag}: unknown {bad[0]!r}; choose from: {', '.join(choices)}")
    return list(dict.fromkeys(names))


def _check(args: argparse.Namespace) -> tuple[list[str], list[str], list[str], float]:
    from reflexarm.experiments.reaction_study import SCENARIOS, STUDY_ARMS

    arms = _names(args.arms, "--arms", STUDY_ARMS)
    from reflexarm.control.collision.react import REACTIONS

    reactions = _names(args.reactions, "--reactions", REACTIONS)
    scenarios = _names(args.scenarios, "--scenarios", SCENARIOS)
    pct = float(args.model_error)
    if not math.isfinite(pct) or not 0.0 <= pct < 100.0:
        raise ConfigError(f"--model-error must be a percentage in [0, 100); got {args.model_error:g}")
    if args.seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer; got {args.seed}")
    return arms, reactions, scenarios, pct


def _detection(args: argparse.Namespace, arms: list[str]) -> dict[str, Any] | None:
    """Each arm's tuned detection pair from ``--detection-study`` (printed), or None without it."""
    if args.detection_study is None:
        if str(args.detection_gain) != "auto":
            raise ConfigError("--detection-gain needs --detection-study (the levels tuned at that gain)")
        return None
    from reflexarm.experiments.reaction_study import study_arm
    from reflexarm.experiments.tuned_detection import load_tuned_detection

    text = str(args.detection_gain).strip()
    try:
        gain = None if text == "auto" else float(text)
    except ValueError:
        raise ConfigError(f"--detection-gain must be a gain [1/s] or auto; got {text!r}") from None
    joints = {a: study_arm(a).robot.joint_names for a in arms}  # (the UR-like arm written to a temporary folder)
    tuned = load_tuned_detection(args.detection_study, arms, joints, gain)
    for name, t in tuned.items():
        levels = ", ".join(f"{v:.3g}" for v in t.levels)
        print(
            f"{name}: detection k_o = {t.gain:g} 1/s, zeta = ({levels}) Nm, model seed {t.model_seed} "
            f"(held-out false alarms {t.alarms_per_hour} /h; from {t.source})",
            file=sys.stderr,
        )
    return tuned


def _floor_summary(rows: list[dict[str, Any]]) -> str:
    """How many runs miss the 1 % energy bar, and how many of those end at or below their rest floor."""
    from reflexarm.experiments.reaction_study import KE_RATIO_GOAL
    from reflexarm.experiments.rest_floor import REST_FLOOR_QUANTILE

    ratio = "kinetic_energy_ratio"
    misses = [r for r in rows if r.get(ratio) is not None and r[ratio] >= KE_RATIO_GOAL]
    at_floor = sum(1 for r in misses if r.get("ke_floor_verdict") == "at floor")
    return (
        f"rest floor: the {100 * REST_FLOOR_QUANTILE:g} % quantile of the kinetic energy of the arm held still at "
        f"its posture at detection by the same controller and noise, no contact; {len(misses)} run(s) miss the "
        f"{100 * KE_RATIO_GOAL:g} % bar, "
        f"{at_floor} of them at or below their rest floor"
    )


def _reaction_study(args: argparse.Namespace) -> int:
    from reflexarm._cli.common import changed_settings, format_table, reaction_settings_of
    from reflexarm.experiments.reaction_study import plot_reaction_study, reaction_measures, run_reaction_study
    from reflexarm.sim import PAPER_NOISE, SensorNoise

    arms, reactions, scenarios, pct = _check(args)
    detection = _detection(args, arms)
    reaction_settings = reaction_settings_of(args.reaction_setting)
    noise = PAPER_NOISE if args.noise == "paper" else SensorNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    noise_text = "the paper's sensor noise" if args.noise == "paper" else "no sensor noise"
    out = Path(args.out)
    total = len(arms) * len(reactions) * len(scenarios)
    print(
        f"reaction study: {len(arms)} arm(s) x {len(scenarios)} scenario(s) x {len(reactions)} reaction(s) = {total} "
        f"runs; +-{pct:g} % model error, {noise_text}, seed {args.seed}"
        + ("; detection tuned per arm (model errors of the arm's tuned model)" if detection else "")
        + (f"; reaction settings{changed_settings(reaction_settings)}" if reaction_settings else ""),
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    done = 0

    def progress(row: dict[str, Any]) -> None:
        nonlocal done
        done += 1
        m = reaction_measures(row)
        ke = "-" if m["ke_ratio"] is None else f"{m['ke_ratio']:.3g}"
        what = f"error: {row['error']}" if row["error"] else f"KE ratio {ke}, guard: {m['guard']}"
        run = f"{row['arm']} / {row['scenario']} / {row['reaction']}"
        print(
            f"[{done}/{total}, {time.perf_counter() - t0:5.1f} s] {run}: {what[:100]}",
            file=sys.stderr,
            flush=True,
        )

    study = run_reaction_study(
        arms,
        reactions,
        scenarios,
        model_error=pct / 100.0,
        model_seed=args.seed,
        noise=noise,
        seed=args.seed,
        folder=out / "arms",
        progress=progress,
        detection=detection,
        reaction_settings=reaction_settings,
    )
    table = []
    for row in study.rows:
        m = reaction_measures(row)
        guard = str(m["guard"] or "")
        m["guard"] = guard if len(guard) <= GUARD_WIDTH else guard[: GUARD_WIDTH - 3] + "..."
        table.append({**row, **m})
    print(format_table(table, COLUMNS))
    paths = study.write(out)
    fig = plot_reaction_study(study, out / "reaction_study.png")
    print(
        f"\nissue 15 asks: KE ratio < 0.01 within 0.5 s, peak after <= at detection, no re-contact "
        f"(brake, retract, compliant), retract ending >= 0.02 m away\n{_floor_summary(study.rows)}\n"
        f"wrote {paths['csv']}, {paths['json']}, {fig} "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return 0
