"""``reflexarm detect``: the collisions in recorded logs (time, joints, link, force, peak residual, delay).

Thin: the stages live in :mod:`reflexarm.detect`; the model, robot, log and level options are the other commands'.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from reflexarm._cli.common import add_model_options, detection_band, filter_gain, format_table, model_choice
from reflexarm._cli.log_options import add_log_options, load_log_from_args
from reflexarm._cli.robot_options import DEFAULT_ROBOT, add_robot_options
from reflexarm._cli.threshold_files import add_detector_options
from reflexarm.errors import ConfigError

_SWITCH = (0, 1)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``detect`` to the top-level parser."""
    from reflexarm.detect.defaults import DEFAULT_DETECTION_GAIN

    p = sub.add_parser(
        "detect",
        help="collision events in recorded logs: time, joints, isolated link, force, peak residual, delay",
        description="Replay each log through the observer at the log's own rate (exact discretization), with "
        "one-sample glitches recognised and repaired, and list the collision events against the levels "
        "(tune-thresholds' thresholds.json or --threshold ZETA): time, joints, the link the collision pipeline "
        "isolates, the force estimate, the peak residual and the delay from the estimated onset (to one period). "
        "Writes events.csv, events.json and per log a figure of the residuals with levels and events.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log(s): CSV / Parquet / npz / ROS 2 bag")
    add_robot_options(p)
    _robot_default_from_model(p)
    add_model_options(p, default_error=0.0, seed_help="seed of --model-error")
    add_log_options(p)
    g = p.add_argument_group("levels and observer")
    g.add_argument(
        "--threshold", required=True, metavar="ZETA|FILE",
        help="the thresholds.json of 'reflexarm tune-thresholds' (its levels, observer and coverage), one level "
        "[Nm] for every joint, or a comma list per joint",
    )  # fmt: skip
    g.add_argument(
        "--detection-observer-gain", type=float, default=None, metavar="K_O",
        help="k_o of the detecting observer [1/s] (default: the thresholds file's, else "
        f"{DEFAULT_DETECTION_GAIN:g}: time constant 10 ms, the shortest impact)",
    )  # fmt: skip
    g.add_argument("--observer-gain", type=float, default=None, metavar="K_O",
                   help="k_o of the compensation observer [1/s] (default: the file's, else 5)")  # fmt: skip
    g.add_argument("--kappa-f", type=int, choices=_SWITCH, default=None, help="friction term in the observer")
    g.add_argument("--kappa-ext", type=int, choices=_SWITCH, default=None, help="EFC: wrist wrench in the observer")
    add_detector_options(g, default="default: the thresholds file's, tuned with it; else {what}")
    p.add_argument("--no-isolation", action="store_true", help="skip the isolation of each event (link, force)")
    p.add_argument("--out", type=Path, default=Path("results/detect"), help="output folder (default results/detect)")
    p.add_argument("--no-figure", action="store_true", help="skip the figures")
    p.set_defaults(func=_detect)


def _robot_default_from_model(p: argparse.ArgumentParser) -> None:
    """``--robot`` left out: the robot the ``--model`` file names (else the default arm)."""
    for action in p._actions:
        if action.dest == "robot":
            action.default = None
            action.help = (
                f"built-in name or .urdf/.xml (MJCF) file (default: the --model file's robot, else {DEFAULT_ROBOT})"
            )


def load_robot_and_model(args: argparse.Namespace) -> tuple[Any, Any, str]:
    """(robot, the controller's model, a line saying which) from the robot and model options; without
    ``--robot`` the ``--model`` file's own robot, as ``validate`` takes it."""
    from reflexarm._cli.robot_options import load_robot_from_args

    choice = model_choice(args)
    if args.robot is None and choice.file is not None:
        from reflexarm.ident.export.model_file import load_model_robot

        robot = load_model_robot(choice.file)
        where = f"robot {robot.name!r} from {choice.file.name} (give --robot to use another file)"
    else:
        args.robot = args.robot or DEFAULT_ROBOT
        robot = load_robot_from_args(args)
        where = f"robot {robot.name}"
    model = choice.build(robot)
    return robot, model, f"{where} ({robot.n} joints); controller model: {choice.label()}"


def _threshold_file(text: str) -> dict[str, Any]:
    path = Path(text)
    if path.suffix.lower() != ".json" or not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}  # read_threshold says what is wrong with it
    return doc if isinstance(doc, dict) else {}


def _settings(args: argparse.Namespace, doc: dict[str, Any]) -> Any:
    from reflexarm.detect.defaults import DEFAULT_DETECTION_GAIN
    from reflexarm.tuning.replay import ObserverSettings

    found = doc.get("observer")
    observer: dict[str, Any] = found if isinstance(found, dict) else {}
    tuned = observer.get("detection_observer_gain") or observer.get("observer_gain")

    def pick(given: Any, key: str, default: Any) -> Any:
        return given if given is not None else observer.get(key, default)

    k_det = pick(args.detection_observer_gain, "detection_observer_gain", None) or tuned or DEFAULT_DETECTION_GAIN
    k_comp = pick(args.observer_gain, "observer_gain", 5.0)
    for value, flag in ((k_det, "--detection-observer-gain"), (k_comp, "--observer-gain")):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{flag} must be a positive gain [1/s]; got {value!r}")
    if tuned is not None and not math.isclose(float(tuned), float(k_det), rel_tol=1e-9):
        print(f"warning: the levels were tuned for a detecting k_o = {tuned:g} 1/s; detecting with {k_det:g} 1/s "
              "(leave out --detection-observer-gain to use the tuned one)", file=sys.stderr)  # fmt: skip
    band = detection_band(pick(args.detection_friction_band, "detection_friction_band", None))
    kf = filter_gain(pick(args.detection_filter_gain, "detection_filter_gain", None))
    return ObserverSettings(
        observer_gain=float(k_comp),
        detection_observer_gain=float(k_det),
        kappa_f=int(pick(args.kappa_f, "kappa_f", 0)),
        kappa_ext=int(pick(args.kappa_ext, "kappa_ext", 0)),
        observer_discretization="exact",
        detection_friction_band=band,
        detection_filter_gain=kf,
    )


def _print_log(d: Any, replay_how: str) -> None:
    from reflexarm.tuning.replay import detector_words

    k_o = d.settings.detection_gain
    own = detector_words(d.settings.detection_friction_band, d.settings.detection_filter_gain)
    print(f"\n{d.source}: {d.t.size} samples, {d.duration:.1f} s at {d.rate_hz:.4g} Hz: delay resolution "
          f"{1e3 * d.dt:.3g} ms (one period); detection observer k_o = {k_o:g} 1/s, exact (k_o dt = {k_o * d.dt:.3g})"
          f"{own}; replay: {replay_how}")  # fmt: skip
    for g in d.glitches:
        print(f"  glitch repaired: joint {g.joint + 1} {g.kind} at t = {g.t:.3f} s "
              f"({g.logged:.4g} -> {g.repaired:.4g})")  # fmt: skip
    for o in d.outside:
        print(f"  warning: {o.line()}")
    if d.fault_ticks:
        print(f"  warning: the controller rejected {d.fault_ticks} samples (their residual holds the last value)")
    if not d.events:
        print("  no collision event")
        return
    rows = [e.row(d.source, d.joint_names) for e in d.events]
    cols = [("t_detect_s", "t [s]", "{:.3f}"), ("delay_s", "delay [ms]", "{:.0f}"), ("joints", "joints", "{}"),
            ("link", "link", "{}"), ("link_name", "link name", "{}"), ("force_N", "force [N]", "{:.1f}"),
            ("peak_ratio", "peak |r|/zeta", "{:.2f}"), ("determined", "determined", "{}")]  # fmt: skip
    for r in rows:
        r["delay_s"] = 1e3 * float(r["delay_s"])  # type: ignore[arg-type]
    print(format_table(rows, cols))


def _detect(args: argparse.Namespace) -> int:
    import warnings

    from reflexarm._cli.common import read_threshold
    from reflexarm.detect.coverage import JointCoverage
    from reflexarm.detect.run import DetectionReport, detect_collisions
    from reflexarm.tuning.replay import ThresholdWarning

    robot, model, line = load_robot_and_model(args)
    print(line, file=sys.stderr)
    doc = _threshold_file(args.threshold)
    settings = _settings(args, doc)
    zeta, source, _ = read_threshold(args.threshold, model, settings.detection_gain)
    cov_doc = doc.get("coverage")
    coverage = [JointCoverage.from_dict(c) for c in cov_doc] if isinstance(cov_doc, list) else None
    if coverage is None:
        print("warning: no coverage stored with the levels (a thresholds.json of tune-thresholds has it): "
              "motions outside what they were tuned on are not flagged", file=sys.stderr)  # fmt: skip
    replay_how = "one call of the C++ core per log (reflexarm.control.replay: Controller.step on every sample)"
    results = []
    for path in args.logs:
        log = load_log_from_args(args, path, model)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ThresholdWarning)
            d = detect_collisions(log, model, zeta, settings=settings, coverage=coverage, isolate=not args.no_isolation)
        for w in caught:
            print(f"warning: {w.message}", file=sys.stderr)
        _print_log(d, replay_how)
        results.append(d)
    method = {
        "levels": source,
        "zeta_Nm": [float(v) for v in (zeta if isinstance(zeta, tuple) else [zeta] * model.n)],
        "observer": settings.as_dict(),
        "replay": replay_how,
        "events": "a sample with some |r_j| > zeta_j; over-samples closer than 5 / k_o (>= 2 samples) are one event",
        "onset": "the last sample before the rise of |r| on the joint that crossed furthest; delay = detection - "
        "onset, to one period of the log",
        "isolation": "the collision pipeline's ContactIsolator on r(peak) - r(onset) at the peak sample",
        "glitches": "one-sample velocity samples that disagree with the positions, and one-joint torque spikes at a "
        "stop, repaired by their neighbours' mean before the replay",
    }
    files = DetectionReport(results, method).write(args.out, figure=not args.no_figure)
    print(f"\nwrote {', '.join(str(f) for f in files.values())}")
    return 0
