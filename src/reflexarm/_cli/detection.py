"""``reflexarm detection-study``: the detection observer's (k_o, zeta) pairs against lag and false alarms.

Thin: the study lives in :mod:`reflexarm.experiments.detection_study`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from reflexarm._cli.threshold_files import add_detector_options

_ARMS = ("atlas_v5_left_arm", "panda", "iiwa14", "ur_like", "iiwa14_frictionless")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``detection-study`` to the top-level parser."""
    p = sub.add_parser(
        "detection-study",
        help="(k_o, zeta) pairs tuned on free motion: detection lag, contact delay, false alarms per hour, pulses",
        description="Per arm: tune per-joint levels for each detection observer gain (exact form) on free-motion "
        "logs (seeds A: other motions and noise of the same arm), count false alarms in --heldout-minutes of free "
        "motion (seeds C), run the demo contact and the link collision with each pair and short force pulses on the "
        "links (seeds B); lag = detection - the "
        "first time (up to detection) the true |tau_ext_j| exceeds zeta_j; own = detection - the first time after "
        "contact that the "
        "observer's input (tau_ext + the model's error torque, its filter taken out) exceeds zeta_j. Writes JSON, CSV "
        "and the lag / false-alarm figure.",
    )
    p.add_argument("--arm", action="append", choices=_ARMS, default=None, help="an arm (repeat; default all five)")
    p.add_argument("--gains", default="5,20,50,100,200,500", metavar="K1,K2,...", help="detection gains [1/s]")
    p.add_argument("--tune-minutes", type=float, default=10.0, help="free motion per tuning model seed (default 10)")
    p.add_argument("--tune-models", type=int, default=3, help="tuning logs (motion/noise seeds; default 3)")
    p.add_argument("--model-seeds", choices=("same", "disjoint"), default="same",
                   help="same: every run on one arm's model (tuned on its own logs, as on a robot; default); "
                   "disjoint: tuning, held-out and contact runs each on another model's errors")  # fmt: skip
    p.add_argument("--heldout-minutes", type=float, default=60.0, help="held-out free motion (default 60)")
    p.add_argument("--pulses", type=int, default=40, help="short force pulses per arm (default 40; 0: none)")
    p.add_argument("--contact-seeds", type=int, default=10,
                   help="noise seeds of each pair's demo contact and link collision (default 10)")  # fmt: skip
    p.add_argument("--rate", type=float, default=0.1, help="false alarms per hour the levels are tuned for (0.1)")
    add_detector_options(p, default="default: {what}, the paper's; with it every run and pair, levels tuned on it")
    p.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                   help="merge detection_study.json files (arms run in parallel) into --out")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("results/detection-study"), help="output folder")
    p.set_defaults(func=_detection_study)


def _print(name: str, arm: dict[str, Any]) -> None:
    def ms(v: Any) -> str:
        return "    -" if v is None else f"{1e3 * v:5.1f}"

    from reflexarm.tuning.replay import detector_words

    own = detector_words(arm.get("detection_friction_band"), arm.get("detection_filter_gain"))
    print(f"\n{name} (plant friction {arm['plant_friction']}{own})")
    print(f"{'k_o':>5} {'zeta max':>8} {'ramp':>5} {'meas':>5} {'FA/h':>6} {'demo lag':>8} {'joint':>5} {'own':>5} "
          f"{'delay':>6} {'link lag':>8} {'joint':>5} {'own':>5} {'delay':>6} {'pulses':>7}")  # fmt: skip
    for p in arm["pairs"]["pairs"]:
        k = p["detection_observer_gain"]
        c = arm["contacts"].get(str(k), {})
        d, lk = c.get("demo", {}), c.get("link", {})
        h = p["heldout"] or {}
        pul = arm.get("pulses", {}).get("caught", {}).get(str(k))
        pulses = "-" if pul is None else f"{pul['caught_eligible']}/{pul['eligible']}"
        print(f"{k:5g} {max(p['collision_Nm']):8.2f} {ms(p['ramp_lag_max_s'])} {ms(p['measured_ramp_lag_max_s'])} "
              f"{h.get('alarms_per_hour', float('nan')):6.2f} {ms(d.get('lag_s')):>8} "
              f"{ms(d.get('lag_detecting_joint_s'))} {ms(d.get('input_lag_s'))} {ms(d.get('delay_s')):>6} "
              f"{ms(lk.get('lag_s')):>8} {ms(lk.get('lag_detecting_joint_s'))} {ms(lk.get('input_lag_s'))} "
              f"{ms(lk.get('delay_s')):>6} {pulses:>7}")  # fmt: skip
    spread = arm.get("contact_seeds") or {}
    if spread:
        n = max(s["seeds"] for c in spread.values() for s in c.values())
        print(f"  over {n} noise seeds, lag on the detecting joints: median / max [ms], within 10 ms, detected "
              "without a true crossing there, not detected")  # fmt: skip
        for k, c in spread.items():
            cells = []
            for scen in ("demo", "link"):
                s = c.get(scen)
                cells.append("-" if s is None else f"{scen} {ms(s['median_s']).strip()} / {ms(s['max_s']).strip()}, "
                             f"{s['within_target']}/{s['seeds']}, {s['detected_without_crossing']}, {s['undetected']}")
            print(f"{float(k):5g}   " + "   ".join(cells))  # fmt: skip


def _detection_study(args: argparse.Namespace) -> int:
    from reflexarm.experiments.detection_study import DetectionStudy, run_detection_study

    if args.merge:
        study = DetectionStudy()
        for path in args.merge:
            doc = json.loads(Path(path).read_text())
            study.arms.update(doc["arms"])
            study.conditions = {**doc["conditions"], **study.conditions}
    else:
        study = run_detection_study(
            args.arm or _ARMS, [float(v) for v in args.gains.split(",")], progress=_print,
            tune_s=60.0 * args.tune_minutes, tune_models=args.tune_models, heldout_s=60.0 * args.heldout_minutes,
            pulses=args.pulses, rate_per_hour=args.rate, model_seeds=args.model_seeds,
            contact_seeds=args.contact_seeds, detection_friction_band=args.detection_friction_band,
            detection_filter_gain=args.detection_filter_gain,
        )  # fmt: skip
    if args.merge:
        for name, arm in study.arms.items():
            _print(name, arm)
    files = study.write(args.out)
    print("\nramp: analytic lag of a 1000 Nm/s ramp (max over joints); meas: max lag measured on the held-out "
          "residual with such ramps added; FA/h: false alarms per hour held out; lag: after the true torque first "
          "exceeds its level on any joint; joint: the same on the detecting joints; own: after the observer's "
          "input first does; lags and delays in ms; pulses: caught / pulses above 3x the model error")  # fmt: skip
    print(f"wrote {', '.join(str(f) for f in files.values())}")
    return 0
