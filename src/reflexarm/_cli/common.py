"""Helpers shared by the command modules: common options, output folders, plain-text tables."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reflexarm._cli.threshold_files import (
    add_detector_options,
    detection_band,
    filter_gain,
    read_threshold,
    tuned_filter_gain,
    tuned_friction_band,
)
from reflexarm.errors import ConfigError

if TYPE_CHECKING:
    from reflexarm.control.collision.react import ReactionSettings
    from reflexarm.robots import RobotModel


def add_common(p: argparse.ArgumentParser, *, default_out: str) -> None:
    """``--out DIR``, ``--seed N`` and ``--quiet`` (no progress bars)."""
    p.add_argument("--out", type=Path, default=Path(default_out), help=f"output folder (default {default_out})")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def out_dir(args: argparse.Namespace) -> Path:
    """Create and return the output folder named by ``--out``."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def format_table(rows: Sequence[dict[str, object]], columns: Sequence[tuple[str, str, str]]) -> str:
    """A fixed-width text table: ``columns`` are (key, header, format); None prints as '-'."""

    def cell(v: object, fmt: str) -> str:
        if v is None:
            return "-"
        try:
            return fmt.format(v)
        except (TypeError, ValueError):
            return str(v)

    body = [[cell(r.get(k), f) for k, _, f in columns] for r in rows]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, (_, h, _) in enumerate(columns)]
    lines = ["  ".join(h.rjust(w) for (_, h, _), w in zip(columns, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(b, widths, strict=True)) for b in body]
    return "\n".join(lines)


#: Default model error of the collision experiments [%]: the paper's simulated arm (Sec. III-C) has
#: uniform +-10 % errors on masses, inertias, COM coordinates and friction; the real arm's error is
#: unknown, Table I shows residual torque errors of a few Nm on the hydraulic joints, which +-10 % gives.
DEFAULT_MODEL_ERROR_PERCENT = 10.0


def add_model_options(
    p: argparse.ArgumentParser,
    *,
    default_error: float = DEFAULT_MODEL_ERROR_PERCENT,
    default_seed: int | None = 0,
    seed_help: str = "seed of the model errors (default 0)",
) -> None:
    """``--model-error PCT``, ``--model-seed N`` and ``--model FILE``: the controller's model.

    The plant always has the robot file's true parameters; the controller gets them perturbed by
    uniform factors within +-PCT % (Sec. III-C), or the identified model in FILE.
    """
    p.add_argument(
        "--model-error",
        type=float,
        default=None,
        metavar="PCT",
        help="the controller's model has uniform errors within +-PCT %% on masses, inertias, COM and friction "
        f"(Sec. III-C; default {default_error:g}; 0: the plant's exact model)",
    )
    p.add_argument("--model-seed", type=int, default=default_seed, help=seed_help)
    p.add_argument(
        "--model",
        type=Path,
        default=None,
        metavar="FILE",
        help="use the identified model in FILE (written by 'identify dynamics') instead of a perturbed one",
    )
    p.set_defaults(_default_model_error=default_error)


@dataclass(frozen=True)
class ModelChoice:
    """The controller's model as the command line chose it: a perturbation level (fraction) and seed,
    or an identified-model file."""

    level: float
    seed: int
    file: Path | None

    def build(self, robot: RobotModel) -> RobotModel:
        """The controller's model of ``robot`` (which stays the plant's true model)."""
        if self.file is not None:
            from reflexarm.ident import load_identified_model

            return load_identified_model(self.file, robot)
        if self.level == 0.0:
            return robot
        from reflexarm.robots import perturb_model

        return perturb_model(robot, self.level, self.seed)

    def describe(self) -> dict[str, object]:
        """JSON-able description for summaries and trace metadata."""
        if self.file is not None:
            return {"source": "identified", "file": str(self.file)}
        if self.level == 0.0:
            return {"source": "exact"}
        return {"source": "perturbed", "level": self.level, "seed": self.seed}

    def label(self) -> str:
        """One-line description for the console."""
        if self.file is not None:
            return f"identified model {self.file}"
        if self.level == 0.0:
            return "the plant's exact model"
        return f"+-{100 * self.level:g} % model errors (seed {self.seed})"


def model_error_percent(args: argparse.Namespace) -> float:
    """The checked ``--model-error`` level [%] of :func:`add_model_options` (0 with ``--model``).

    Raises:
        ConfigError: a negative or >= 100 % level, a negative seed, a missing ``--model`` file, or
            ``--model`` together with an explicit ``--model-error`` (an identified model is used as it is).
    """
    pct = args.model_error
    if args.model is not None:
        if pct is not None and pct != 0.0:
            raise ConfigError(
                f"--model {args.model} is used as identified; got --model-error {pct:g} as well (drop one of them)"
            )
        if not Path(args.model).is_file():
            raise ConfigError(f"--model: no such file {str(args.model)!r}")
        pct = 0.0
    if pct is None:
        pct = float(getattr(args, "_default_model_error", DEFAULT_MODEL_ERROR_PERCENT))
    if not math.isfinite(pct) or not 0.0 <= pct < 100.0:
        raise ConfigError(f"--model-error must be a percentage in [0, 100); got {pct:g}")
    if args.model_seed is not None and args.model_seed < 0:
        raise ConfigError(f"--model-seed must be a non-negative integer; got {args.model_seed}")
    return float(pct)


def model_choice(args: argparse.Namespace) -> ModelChoice:
    """The :class:`ModelChoice` of ``--model-error``/``--model-seed``/``--model`` (see :func:`add_model_options`)."""
    pct = model_error_percent(args)
    return ModelChoice(pct / 100.0, int(args.model_seed), None if args.model is None else Path(args.model))


def model_error_line(robot: RobotModel, model: RobotModel) -> str:
    """How far the controller's ``model`` is from the plant's ``robot``: median relative error of g(q)
    and M(q) over 200 seeded random states (what a level of uniform factors achieves on this arm)."""
    if model is robot:
        return "achieved model error: none (exact model)"
    from reflexarm.robots.perturbation import measure_model_error

    size = measure_model_error(robot, model)
    return (
        f"achieved model error over {size.n_states} random states: g(q) median {100 * size.gravity_median:.1f} % "
        f"(max {100 * size.gravity_max:.1f} %), M(q) median {100 * size.mass_matrix_median:.1f} %"
    )


#: Reactions the collision commands offer (``--reaction``): passed to ``Controller(reaction=...)`` as given,
#: so a name the installed controller does not know yet is refused there, naming its choices.
REACTION_CHOICES = ("gravity", "brake", "retract", "compliant", "none")


def add_detection_options(
    p: argparse.ArgumentParser,
    *,
    observer_gain: float | None = 5.0,
    threshold: str = "11",
    reaction: str = "gravity",
    note: str = "",
) -> None:
    """``--threshold ZETA|FILE``, ``--observer-gain K_O``, ``--detection-observer-gain K_O`` and
    ``--reaction``: the collision detection (12) and reaction of the detecting run. ``observer_gain`` None:
    the command's own default (named in ``note``)."""
    g = p.add_argument_group("collision detection" + (f" ({note})" if note else ""))
    g.add_argument(
        "--threshold",
        default=threshold,
        metavar="ZETA|FILE",
        help="zeta: one level [Nm] for every joint, a comma list per joint (model order), or the thresholds.json "
        f"written by 'reflexarm tune-thresholds' (its collision level per joint) (default {threshold}, the paper's)",
    )
    g.add_argument(
        "--observer-gain",
        type=float,
        default=observer_gain,
        metavar="K_O",
        help="k_o of the observer (4)-(6) [1/s] "
        + ("(default: the command's own)" if observer_gain is None else f"(default {observer_gain:g}, the paper's)"),
    )
    g.add_argument(
        "--detection-observer-gain",
        type=float,
        default=None,
        metavar="K_O",
        help="k_o of a second observer used for detection only [1/s] (default: none, the first one detects)",
    )
    g.add_argument(
        "--observer-discretization",
        choices=("euler", "exact"),
        default=None,
        help="the observers' discretization: euler (the paper's, needs k_o dt < 1) or exact (the first-order "
        "filter's exact form, stable at any gain; what 'tune-thresholds --detection-gains' tunes) (default: exact "
        "with --detection-observer-gain, else euler)",
    )
    add_detector_options(
        g, default="default: a thresholds.json's, tuned with it; else {what}", needs="; needs --detection-observer-gain"
    )
    g.add_argument(
        "--reaction",
        choices=REACTION_CHOICES,
        default=reaction,
        help=f"what a detected collision does (default {reaction})",
    )
    add_reaction_setting_option(g)


def add_reaction_setting_option(g: argparse._ActionsContainer) -> None:
    """``--reaction-setting KEY=VALUE[,KEY=VALUE...]`` (repeatable): fields of ReactionSettings."""
    g.add_argument(
        "--reaction-setting",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="a reaction setting other than its default, e.g. retract_distance=0.1,max_retract_time=0.4 (repeat or "
        "comma-separate; keys: the fields of reflexarm.control.ReactionSettings: brake_time, retract_distance, "
        "retract_speed, max_retract_time, velocity_fraction, compliant_stiffness_factor, rest_time, ...)",
    )


def changed_settings(settings: ReactionSettings | None) -> str:
    """", with KEY=VALUE, ..." for the fields of ``settings`` that differ from their defaults ("" for none)."""
    if settings is None:
        return ""
    default = type(settings)()
    changed = [f"{k}={v:g}" for k, v in asdict(settings).items() if v != getattr(default, k)]
    return f" ({', '.join(changed)})" if changed else ""


def reaction_settings_of(items: Sequence[str] | None) -> ReactionSettings | None:
    """The ReactionSettings of ``--reaction-setting`` (None when not given); its own checks name a bad value.

    Raises:
        ConfigError: not KEY=VALUE, an unknown key (the keys are listed), a value that is not a number (not true or
            false for retract_waits_for_estimate).
    """
    from dataclasses import fields

    from reflexarm.control.collision.react import ReactionSettings

    if not items:
        return None
    keys = [f.name for f in fields(ReactionSettings)]
    values: dict[str, float | int | bool] = {}
    for part in (p.strip() for item in items for p in item.split(",")):
        key, sep, text = (x.strip() for x in part.partition("="))
        if not sep or key not in keys:
            raise ConfigError(f"--reaction-setting expects KEY=VALUE, KEY one of: {', '.join(keys)}; got {part!r}")
        if key == "retract_waits_for_estimate":
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ConfigError(f"--reaction-setting {key} must be true or false; got {text!r}")
            values[key] = text.lower() in ("true", "1", "yes")
            continue
        integer = key == "isolation_points_per_tick"
        try:
            values[key] = int(text) if integer else float(text)
        except ValueError:
            kind = "an integer" if integer else "a number"
            raise ConfigError(f"--reaction-setting {key} must be {kind}; got {text!r}") from None
    return ReactionSettings(**values)  # type: ignore[arg-type]


def detector_text(
    gain: float | None, band: float | None, filter_gain: float | None, discretization: str = "euler"
) -> str:
    """The console words for what is set of a detection observer's gain, friction band and second stage (and the
    observers' form when not Euler): ", detection k_o = 100 1/s (exact observers), its friction in a ..."."""
    text = "" if gain is None else f", detection k_o = {gain:g} 1/s"
    if discretization != "euler":
        text += f" ({discretization} observers)"
    if band is not None:
        text += f", its friction in a {band:g} rad/s band"
    if filter_gain is not None:
        text += f", a second stage of K_f = {filter_gain:g} 1/s"
    return text


@dataclass(frozen=True)
class DetectionChoice:
    """The detection settings the command line chose: zeta [Nm] (scalar or per joint), observer gains
    [1/s], reaction, and where zeta came from."""

    threshold: float | tuple[float, ...]
    observer_gain: float | None
    detection_observer_gain: float | None
    reaction: str
    source: str
    tuned_gain: float | None = None  # the detecting k_o a thresholds.json was tuned for
    observer_discretization: str = "euler"
    detection_friction_band: float | None = None  # the detection observer's own friction band [rad/s]
    reaction_settings: ReactionSettings | None = None  # --reaction-setting (None: the defaults)
    detection_filter_gain: float | None = None  # K_f of the detection residual's second stage [1/s]

    def label(self) -> str:
        """One line for the console."""
        if isinstance(self.threshold, tuple):
            zeta = "(" + ", ".join(f"{v:.3g}" for v in self.threshold) + ") Nm"
        else:
            zeta = f"{self.threshold:g} Nm"
        gains = "" if self.observer_gain is None else f", k_o = {self.observer_gain:g} 1/s"
        gains += detector_text(self.detection_observer_gain, self.detection_friction_band, self.detection_filter_gain,
                               self.observer_discretization)  # fmt: skip
        src = "" if self.source == "command line" else f" (from {self.source})"
        return f"zeta = {zeta}{src}{gains}, reaction {self.reaction}{changed_settings(self.reaction_settings)}"

    def describe(self) -> dict[str, object]:
        """JSON-able description for summaries."""
        return {
            "threshold_Nm": list(self.threshold) if isinstance(self.threshold, tuple) else self.threshold,
            "threshold_source": self.source,
            "observer_gain_per_s": self.observer_gain,
            "detection_observer_gain_per_s": self.detection_observer_gain,
            "observer_discretization": self.observer_discretization,
            "detection_friction_band_rad_s": self.detection_friction_band,
            "detection_filter_gain_per_s": self.detection_filter_gain,
            "reaction": self.reaction,
            "reaction_settings": None if self.reaction_settings is None else asdict(self.reaction_settings),
        }


def _gain(value: float | None, flag: str) -> float | None:
    if value is not None and (not math.isfinite(value) or value <= 0.0):
        raise ConfigError(f"{flag} must be a positive gain [1/s]; got {value:g}")
    return value


def detection_choice(args: argparse.Namespace, robot: RobotModel) -> DetectionChoice:
    """The checked :class:`DetectionChoice` of :func:`add_detection_options` for ``robot``.

    Raises:
        ConfigError: a bad ``--threshold`` (see :func:`read_threshold`) or a non-positive gain.
    """
    running = args.detection_observer_gain if args.detection_observer_gain is not None else args.observer_gain
    zeta, source, tuned = read_threshold(args.threshold, robot, running)
    discretization = getattr(args, "observer_discretization", None)
    if discretization is None:
        discretization = "exact" if args.detection_observer_gain is not None else "euler"
    band = getattr(args, "detection_friction_band", None)
    if band is None and source != "command line":  # levels tuned with the detection observer's own friction
        band = tuned_friction_band(args.threshold)
    band = detection_band(band)
    if band is not None and args.detection_observer_gain is None:
        raise ConfigError("--detection-friction-band (or a thresholds.json tuned with one) needs "
                          "--detection-observer-gain: the friction goes into the detection observer")  # fmt: skip
    kf = getattr(args, "detection_filter_gain", None)
    if kf is None and source != "command line":  # levels tuned on the residual through the second stage
        kf = tuned_filter_gain(args.threshold)
    return DetectionChoice(
        detection_filter_gain=filter_gain(kf),
        reaction_settings=reaction_settings_of(getattr(args, "reaction_setting", None)),
        detection_friction_band=band,
        observer_discretization=discretization,
        threshold=zeta,
        observer_gain=_gain(args.observer_gain, "--observer-gain"),
        detection_observer_gain=_gain(args.detection_observer_gain, "--detection-observer-gain"),
        reaction=args.reaction,
        source=source,
        tuned_gain=tuned,
    )


def tuned_gain_note(choice: DetectionChoice, default_gain: float) -> str | None:
    """A warning line when a thresholds file was tuned for another detecting k_o than the run uses."""
    if choice.tuned_gain is None:
        return None
    running = choice.detection_observer_gain or choice.observer_gain or default_gain
    if math.isclose(running, choice.tuned_gain, rel_tol=1e-9):
        return None
    return (
        f"warning: the thresholds in {choice.source} were tuned for a detecting k_o = {choice.tuned_gain:g} 1/s; "
        f"this run detects with k_o = {running:g} 1/s (give --observer-gain or --detection-observer-gain "
        f"{choice.tuned_gain:g})"
    )
