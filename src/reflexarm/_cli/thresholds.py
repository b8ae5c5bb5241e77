"""``reflexarm tune-thresholds``: collision and contact thresholds per joint from the user's free-motion logs.

Thin: the study, its report, its figures and files live in :mod:`reflexarm.tuning`.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

from reflexarm._cli.common import add_model_options
from reflexarm._cli.detect import _robot_default_from_model, load_robot_and_model
from reflexarm._cli.log_options import add_log_options, load_log_from_args
from reflexarm._cli.robot_options import DEFAULT_ROBOT, add_robot_options, load_robot_from_args
from reflexarm._cli.threshold_files import add_detector_options

_SWITCH = (0, 1)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``tune-thresholds`` to the top-level parser."""
    from reflexarm.tuning.defaults import DEFAULT_CONTACT_RATE, DEFAULT_METHOD, DEFAULT_RATE
    from reflexarm.tuning.tail import METHODS

    p = sub.add_parser(
        "tune-thresholds",
        help="per-joint collision and contact thresholds (zeta) for false-alarm rates you give, from free-motion logs",
        description="Replay the observer (4)-(6) on free-motion logs (no contact) with your model and observer "
        "settings, fit the tail of each joint's |residual| and propose a collision level (--rate false alarms per "
        "hour for the arm) and a lower contact level (--contact-rate), with the detection delay of a torque step.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="free-motion log(s): CSV / Parquet / npz / ROS 2 bag, or a "
                   "reflexarm trace (.parquet); several logs are pooled")  # fmt: skip
    add_robot_options(p)
    _robot_default_from_model(p)
    add_model_options(
        p, default_error=0.0, seed_help="seed of --model-error (to replay a simulated arm's perturbed model)"
    )
    add_log_options(p)
    _add_observer_options(p)
    t = p.add_argument_group("levels")
    t.add_argument(
        "--rate", type=float, default=DEFAULT_RATE, metavar="PER_HOUR",
        help=f"false alarms per hour of the collision level, whole arm (default {DEFAULT_RATE:g})",
    )  # fmt: skip
    t.add_argument(
        "--contact-rate", type=float, default=DEFAULT_CONTACT_RATE, metavar="PER_HOUR",
        help=f"false alarms per hour of the contact level (default {DEFAULT_CONTACT_RATE:g}, one a minute)",
    )  # fmt: skip
    t.add_argument(
        "--step-torque", type=float, default=30.0, metavar="NM",
        help="external torque step at a joint whose detection delay is reported [Nm] (default 30)",
    )  # fmt: skip
    t.add_argument(
        "--step-force", type=float, default=None, metavar="N",
        help="also: delay of a force step [N] at the end effector along the base axes (J^T F at the logs' median "
        "posture)",
    )  # fmt: skip
    t.add_argument(
        "--method",
        choices=METHODS,
        default=DEFAULT_METHOD,
        help=f"tail model: exponential (xi = 0) or gpd (generalized Pareto, shape fitted) (default {DEFAULT_METHOD})",
    )
    t.add_argument("--gap", type=float, default=None, metavar="S", help="declustering gap [s] (default 5 / k_o)")
    t.add_argument(
        "--allow-extrapolation", action="store_true", help="warn instead of refusing when the logs are too short"
    )
    _add_pair_options(p)
    p.add_argument(
        "--recorded-residual",
        action="store_true",
        help="reflexarm traces: tune on the residual their controller computed online (with the measured noise) "
        "instead of replaying it (a trace holds true velocities); right when that controller is the one you run",
    )
    p.add_argument(
        "--allow-unmoved", action="store_true",
        help="write levels for joints that did not move in the logs (marked 'moved': false); default: refuse",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("results/thresholds"), help="output folder")
    p.add_argument("--no-figure", action="store_true", help="skip the figures")
    p.set_defaults(func=_tune)


def _add_observer_options(p: argparse.ArgumentParser) -> None:
    """The observer settings the levels are for (the ones the user runs)."""
    g = p.add_argument_group("observer (the settings you run)")
    g.add_argument("--observer-gain", type=float, default=5.0, help="k_o [1/s] (default 5, the paper's)")
    g.add_argument(
        "--detection-observer-gain", type=float, default=None, help="k_o of a separate detection observer [1/s]"
    )
    g.add_argument(
        "--observer-discretization", choices=("euler", "exact"), default=None,
        help="euler (k_o dt < 1) or exact (stable at any gain, what 'detect' runs) (default: exact with "
        "--detection-observer-gain, else euler)",
    )  # fmt: skip
    g.add_argument("--kappa-f", type=int, choices=_SWITCH, default=0, help="friction term in the observer (default 0)")
    add_detector_options(
        g, default="default: {what}; with --detection-gains, every pair's", needs="; whatever --kappa-f; needs "
        "--detection-observer-gain"
    )  # fmt: skip
    g.add_argument("--kappa-ext", type=int, choices=_SWITCH, default=0, help="EFC: wrist wrench in the observer")
    g.add_argument("--kappa-eps", type=int, choices=_SWITCH, default=0, help="disturbance compensation (recorded only)")


def _add_pair_options(p: argparse.ArgumentParser) -> None:
    """The (k_o, zeta) pair options of ``tune-thresholds --detection-gains``."""
    d = p.add_argument_group("(k_o, zeta) pairs (exact discretization)")
    d.add_argument(
        "--detection-gains", default=None, metavar="K1,K2,...",
        help="also propose levels for a detection observer at each of these gains [1/s] (exact form), with the "
        "lag each gives and its false alarms on --heldout logs; written under 'detection_pairs' of thresholds.json "
        "(--threshold FILE --detection-observer-gain K then runs the pair at K)",
    )  # fmt: skip
    d.add_argument(
        "--heldout", nargs="+", default=[], metavar="LOG",
        help="free-motion logs of other seeds than LOG: false alarms per gain counted on them",
    )  # fmt: skip
    d.add_argument(
        "--ramp-slope", type=float, default=1000.0, metavar="NM_PER_S",
        help="ramp of external torque whose lag is reported [Nm/s] (default 1000)",
    )  # fmt: skip
    d.add_argument(
        "--step-size", type=float, default=2.0, metavar="X",
        help="step of external torque whose lag is reported, in multiples of zeta (default 2)",
    )  # fmt: skip


def _load(args: argparse.Namespace, path: str, robot: Any) -> Any:
    from reflexarm.tuning.replay import is_trace_file, load_free_motion_log, recorded_residual

    if args.recorded_residual:
        return recorded_residual(path, robot.n)
    if is_trace_file(path):
        return load_free_motion_log(path, robot)
    return load_log_from_args(args, path, robot)


def _tune(args: argparse.Namespace) -> int:
    from reflexarm._cli.threshold_files import filter_gain
    from reflexarm.errors import ConfigError
    from reflexarm.tuning import ObserverSettings, ThresholdWarning, tune_thresholds

    if args.detection_friction_band is not None and args.detection_observer_gain is None:
        raise ConfigError(
            "--detection-friction-band needs --detection-observer-gain: the friction goes into the detection "
            "observer, whose levels the file holds (--detection-gains then tunes its pairs with it too)"
        )
    if args.recorded_residual:  # the residual is the run's: its model, not --model (kinematics for J^T F only)
        args.robot = args.robot or DEFAULT_ROBOT
        robot = model = load_robot_from_args(args)
        print(
            f"robot {robot.name} ({robot.n} joints); controller model: the one each trace's run used (its residual "
            "was recorded online); --model and --model-error are ignored",
            file=sys.stderr,
        )
    else:
        robot, model, line = load_robot_and_model(args)
        print(line, file=sys.stderr)
        if model is not robot:
            print(_model_error_line(robot, model, args), file=sys.stderr)
    discretization = args.observer_discretization
    if discretization is None:
        discretization = "exact" if args.detection_observer_gain is not None else "euler"
    settings = ObserverSettings(
        observer_gain=args.observer_gain,
        detection_observer_gain=args.detection_observer_gain,
        kappa_f=args.kappa_f,
        kappa_ext=args.kappa_ext,
        kappa_eps=args.kappa_eps,
        observer_discretization=discretization,
        detection_friction_band=args.detection_friction_band,
        detection_filter_gain=filter_gain(args.detection_filter_gain),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ThresholdWarning)
        try:
            proposal = tune_thresholds(
                [_load(args, p, model) if args.recorded_residual else p for p in args.logs],
                model,
                settings=settings,
                rate_per_hour=args.rate,
                contact_rate_per_hour=args.contact_rate,
                step_torque=args.step_torque,
                step_force=args.step_force,
                method=args.method,
                gap_s=args.gap,
                allow_extrapolation=args.allow_extrapolation,
                load=lambda path: _load(args, str(path), model),
            )
        finally:  # what the study warned about is printed even when it then fails
            for w in caught:
                print(f"warning: {w.message}", file=sys.stderr)
    for w in caught:  # a warning the study also noted (e.g. "... -- extrapolating as asked") is noted once
        if not any(str(w.message).split(" -- ")[0] in note for note in proposal.notes):
            proposal.notes.append(str(w.message))
    if args.recorded_residual:
        proposal.notes.append(
            "residuals recorded online by the traces' controllers, with the model and observer each run used: "
            "--model, --model-error and the observer options were not applied (the delays use --observer-gain)"
        )
    _check_coverage(proposal, args.allow_unmoved)
    pairs = _pairs(args, model, settings) if args.detection_gains else None
    if pairs is not None:
        proposal.detection_pairs = pairs.as_dict()
    from reflexarm.tuning._report import format_pairs, format_report
    from reflexarm.tuning.output import write_thresholds

    files = write_thresholds(proposal, args.out, figure=not args.no_figure)
    print(format_report(proposal))
    if pairs is not None:
        import pandas as pd

        files["pairs_csv"] = Path(args.out) / "detection_pairs.csv"
        pd.DataFrame(pairs.rows()).to_csv(files["pairs_csv"], index=False, float_format="%.6g")
        print("\n" + format_pairs(pairs))
    print(f"\nwrote {', '.join(str(f) for f in files.values())}")
    return 0


def _pairs(args: argparse.Namespace, model: Any, settings: Any) -> Any:
    """The (k_o, zeta) pairs of ``--detection-gains`` on the same logs, held out on ``--heldout``."""
    from reflexarm.errors import ConfigError
    from reflexarm.tuning import ThresholdWarning, parse_gains, propose_detection_pairs

    if args.recorded_residual:
        raise ConfigError("--detection-gains replays the logs at each gain; it cannot use --recorded-residual")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ThresholdWarning)
        pairs = propose_detection_pairs(
            args.logs,
            model,
            parse_gains(args.detection_gains),
            heldout=args.heldout,
            settings=settings,
            rate_per_hour=args.rate,
            contact_rate_per_hour=args.contact_rate,
            ramp_slope=args.ramp_slope,
            step_size=args.step_size,
            method=args.method,
            allow_extrapolation=args.allow_extrapolation,
            load=lambda path: _load(args, str(path), model),
        )
    for w in caught:
        print(f"warning (pairs): {w.message}", file=sys.stderr)
    return pairs


def _model_error_line(robot: Any, model: Any, args: argparse.Namespace) -> str:
    """How far the controller's model is from the robot file's parameters, saying what is compared (issue 18
    item 8): an identified model against the robot file, not against the arm that produced the logs."""
    from reflexarm.robots.perturbation import measure_model_error

    size = measure_model_error(robot, model)
    numbers = (
        f"over {size.n_states} random states: g(q) median {100 * size.gravity_median:.1f} % (max "
        f"{100 * size.gravity_max:.1f} %), M(q) median {100 * size.mass_matrix_median:.1f} %"
    )
    if args.model is not None:
        return (
            f"achieved model error: the identified model {Path(args.model).name} against the robot file "
            f"{robot.name!r} (its nominal parameters; not against the arm that recorded the logs, which no file "
            f"describes) {numbers}"
        )
    what = "the perturbed model against the robot file"
    return f"achieved model error: {what} {robot.name!r} (the simulated arm's true parameters) {numbers}"


def _check_coverage(proposal: Any, allow_unmoved: bool) -> None:
    """Refuse levels for joints that did not move in the logs (unless ``allow_unmoved``: they are written marked
    ``"moved": false``)."""
    from reflexarm.errors import ConfigError

    still = proposal.unmoved
    if not still:
        return
    lines = "\n".join(proposal.coverage[j].line() for j in still)
    if not allow_unmoved:
        raise ConfigError(
            f"joint(s) {', '.join(str(j + 1) for j in still)} did not move in the logs: a level tuned on a joint at "
            f"rest describes its noise only and raises false alarms when it moves\n{lines}\nrecord free motion that "
            "moves every joint, or give --allow-unmoved to write the levels marked 'moved': false"
        )
    proposal.notes.append(
        f"levels of joint(s) {', '.join(str(j + 1) for j in still)} written although they did not move "
        "(--allow-unmoved): marked 'moved': false; 'reflexarm detect' warns when a log moves them"
    )
