"""Helpers shared by the command modules: common options, output folders, plain-text tables."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reflexarm.errors import ConfigError

if TYPE_CHECKING:
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
