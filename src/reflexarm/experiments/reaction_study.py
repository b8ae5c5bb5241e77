"""Reaction study: what each reaction to a detected collision leaves the arm doing, on several arms.

For every arm of :data:`STUDY_ARMS` (Atlas, Panda, iiwa14, the UR5-like 6-DoF arm reflexarm writes, and the
iiwa14 with no joint friction or damping at all) and every scenario (:data:`SCENARIOS`: the demo's
end-effector contact with the cinderblock, the link collision with the stick), the Coll.Det run is repeated
with each reaction (default :data:`STUDY_REACTIONS`) under the default conditions of the collision
experiments (the paper's sensor noise, +-10 % model errors, k_o = 5 1/s, zeta = 11 Nm), and each run is
measured from its truth by :func:`~reflexarm.experiments.collision_events.collision_outcome`.

A reaction the installed :class:`~reflexarm.control.Controller` does not know gives a row whose ``error``
names it (the refusal's message), so the study runs on whatever reactions exist.
"""

from __future__ import annotations

import tempfile
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from reflexarm.control.collision.react import ReactionSettings
from reflexarm.errors import ConfigError
from reflexarm.experiments.collision import (
    EE_SETTINGS,
    LINK_SETTING,
    CollisionSetting,
    run_ee_collision,
    run_link_collision,
)
from reflexarm.experiments.collision_events import (
    KE_RESIDUAL_SHARE,
    CollisionOutcome,
    collision_outcome,
    write_outcomes,
)
from reflexarm.experiments.rest_floor import RestFloor, floor_verdict, rest_floor
from reflexarm.experiments.tuned_detection import TunedDetection
from reflexarm.robots import RobotModel, load_robot
from reflexarm.sim import PAPER_NOISE, SensorNoise, Trace

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "KE_RATIO_GOAL",
    "PEAK_RATIO_GOAL",
    "SCENARIOS",
    "STUDY_ARMS",
    "STUDY_REACTIONS",
    "ReactionStudy",
    "StudyArm",
    "plot_reaction_study",
    "reaction_measures",
    "reaction_study_figure",
    "run_reaction_study",
    "study_arm",
]

#: The arms of the study, by name (see :func:`study_arm`).
STUDY_ARMS = ("atlas_v5_left_arm", "panda", "iiwa14", "ur_like", "iiwa14_frictionless")

#: The reactions the study compares (issue 15); "none" (detection reported only) may be added as a baseline.
STUDY_REACTIONS = ("gravity", "brake", "retract", "compliant")

#: The contact scenarios: the demo's end-effector contact (cinderblock), the link collision (the paper's stick,
#: pushed on after detection) and the link running into a held stick (a static obstacle).
SCENARIOS = ("demo", "link", "link_held")


@dataclass(frozen=True)
class StudyArm:
    """One arm of the study: its name, the plant's true model and the true joint friction ("file"/"none")."""

    name: str
    robot: RobotModel
    plant_friction: str = "file"


def study_arm(name: str, folder: str | Path | None = None) -> StudyArm:
    """The arm ``name`` of :data:`STUDY_ARMS`: a built-in robot; "ur_like" the UR5-like arm of
    :func:`~reflexarm.robots.example_arms.write_ur_like_arm` written into ``folder`` (default a temporary
    folder) and cut at its flange ``tool0``; "iiwa14_frictionless" the built-in iiwa14 whose true joints
    have no friction and no damping (``plant_friction="none"`` of the collision experiments).

    Raises:
        ConfigError: an unknown name, naming the choices.
    """
    if name == "ur_like":
        from reflexarm.robots.example_arms import UR_LIKE_TIP, write_ur_like_arm

        target = Path(tempfile.mkdtemp(prefix="reflexarm_ur_like_")) if folder is None else Path(folder)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the file's ros2_control/gazebo tags and gripper are reported there
            robot = load_robot(write_ur_like_arm(target), tip=UR_LIKE_TIP)
        return StudyArm(name, robot)
    if name == "iiwa14_frictionless":
        return StudyArm(name, load_robot("iiwa14"), plant_friction="none")
    if name in ("atlas_v5_left_arm", "panda", "iiwa14"):
        return StudyArm(name, load_robot(name))
    raise ConfigError(f"unknown study arm {name!r}; choose one of: {', '.join(STUDY_ARMS)}")


@dataclass
class ReactionStudy:
    """The study's rows: one per (arm, scenario, reaction), each the run's
    :class:`~reflexarm.experiments.collision_events.CollisionOutcome` fields beside ``arm``, ``scenario``,
    ``reaction``, ``plant_friction`` and ``error`` (None, or why the run could not be made)."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    conditions: dict[str, Any] = field(default_factory=dict)

    def outcome(self, arm: str, scenario: str, reaction: str) -> CollisionOutcome | None:
        """The outcome of one run, or None if it failed (or was not run)."""
        names = set(CollisionOutcome.__dataclass_fields__)
        for r in self.rows:
            if (r["arm"], r["scenario"], r["reaction"]) == (arm, scenario, reaction) and r["error"] is None:
                values = {k: v for k, v in r.items() if k in names}
                values["joints_crossed"] = tuple(values["joints_crossed"])
                if values["contact_point"] is not None:
                    values["contact_point"] = tuple(values["contact_point"])
                return CollisionOutcome(**values)
        return None

    def write(self, folder: str | Path, name: str = "reaction_study") -> dict[str, Path]:
        """Write ``{name}.json`` (rows and conditions) and ``{name}.csv`` (rows) into ``folder``."""
        import json

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"csv": write_outcomes(self.rows, out / f"{name}.csv"), "json": out / f"{name}.json"}
        paths["json"].write_text(json.dumps({"conditions": self.conditions, "rows": self.rows}, indent=2))
        return paths


def _guard(trace: Trace) -> dict[str, Any]:
    """The guard's verdict and the detector's re-detections from the controller's event record
    (``trace.meta["collision_event"]``)."""
    event = trace.meta.get("collision_event")
    if not isinstance(event, dict):
        return {"guard": "no detection", "guard_still_moving": None, "redetections": None}
    if event.get("text"):
        verdict = str(event["text"])
    elif event.get("guard_checked"):
        verdict = "at rest"
    else:
        verdict = "not checked (run ended first)"
    # the detector's own count of re-contacts: crossings again after the residual fell below half of every level
    return {
        "guard": verdict,
        "guard_still_moving": bool(event.get("still_moving")),
        "redetections": event.get("recrossings"),
    }


def _setting(
    scenario: str, reaction: str, tuned: TunedDetection | None = None, settings: ReactionSettings | None = None
) -> CollisionSetting:
    """The collision setting of a scenario's run: the demo's Coll.Det, or the link collision's; with ``tuned``, its
    detection observer (exact form) and per-joint levels detect; ``settings``: the reactions' (None: defaults)."""
    base = next(s for s in EE_SETTINGS if s.name == "Coll.Det") if scenario == "demo" else LINK_SETTING
    if tuned is not None:
        base = replace(
            base,
            detection_observer_gain=tuned.gain,
            threshold=tuned.levels,
            observer_discretization="exact",
            detection_friction_band=tuned.friction_band,
            detection_filter_gain=tuned.filter_gain,
        )
    return replace(base, reaction=reaction, reaction_settings=settings)


def _run_one(
    arm: StudyArm, scenario: str, setting: CollisionSetting, kwargs: dict[str, Any]
) -> tuple[CollisionOutcome, Trace]:
    if scenario == "demo":
        trace = run_ee_collision(setting, robot=arm.robot, plant_friction=arm.plant_friction, **kwargs)
    else:
        trace = run_link_collision(
            setting=setting,
            robot=arm.robot,
            plant_friction=arm.plant_friction,
            stick="held" if scenario == "link_held" else "pushed",
            **kwargs,
        )
    return collision_outcome(trace, arm.robot, name=f"{arm.name}/{scenario}/{setting.reaction}"), trace


def _floor(
    arm: StudyArm, setting: CollisionSetting, outcome: CollisionOutcome, trace: Trace, kwargs: dict[str, Any]
) -> RestFloor | None:
    """The rest floor at the run's posture at detection (None without a detection), with the run's ``setting``
    reacting to nothing."""
    if outcome.detected_s is None:
        return None
    i_d = int(np.searchsorted(trace.t, outcome.detected_s - 1e-9))
    quiet = replace(setting, reaction="none")
    return rest_floor(arm.robot, quiet, trace.q[i_d], plant_friction=arm.plant_friction, **kwargs)


def _study_row(
    arm: StudyArm,
    scenario: str,
    reaction: str,
    kwargs: dict[str, Any],
    tuned: TunedDetection | None,
    floor: RestFloor | None,
    rest_floors: bool,
    settings: ReactionSettings | None = None,
) -> tuple[dict[str, Any], RestFloor | None]:
    """One run's row (its outcome, the guard, the rest floor) and the scenario's rest floor (measured on the first
    run with a detection, when ``rest_floors`` and not given)."""
    row: dict[str, Any] = {
        "arm": arm.name,
        "scenario": scenario,
        "reaction": reaction,
        "plant_friction": arm.plant_friction,
        "error": None,
    }
    try:
        setting = _setting(scenario, reaction, tuned, settings)
        outcome, trace = _run_one(arm, scenario, setting, kwargs)
        row.update(outcome.as_dict())
        row.update(_guard(trace))
        if rest_floors and floor is None:
            floor = _floor(arm, setting, outcome, trace, kwargs)
        if floor is not None:
            row.update(floor.as_dict())
            row["ke_floor_verdict"] = floor_verdict(row)
    except ConfigError as e:  # e.g. a reaction this controller does not offer (yet)
        row["error"] = str(e)
    row["detection_gain_per_s"] = None if tuned is None else tuned.gain
    return row, floor


def run_reaction_study(
    arms: Sequence[str | StudyArm] = STUDY_ARMS,
    reactions: Sequence[str] = STUDY_REACTIONS,
    scenarios: Sequence[str] = SCENARIOS,
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    folder: str | Path | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
    rest_floors: bool = True,
    detection: Mapping[str, TunedDetection] | None = None,
    reaction_settings: ReactionSettings | None = None,
) -> ReactionStudy:
    """Run the demo contact and the link collision with each reaction on each arm (module docstring).

    Args:
        arms: names of :data:`STUDY_ARMS` (see :func:`study_arm`) or :class:`StudyArm` objects.
        reactions: names for ``Controller(reaction=...)``; one the controller refuses gives a row with
            ``error`` set.
        scenarios: a subset of :data:`SCENARIOS`.
        model_error: the controller's model error, a fraction (None: the collision experiments' 10 %).
        model_seed: seed of the model errors.
        noise: sensor noise (default the paper's).
        seed: seed of the sensor noise.
        folder: where the UR5-like arm's files are written (default a temporary folder).
        progress: called with each row when it is done (e.g. to print it).
        rest_floors: also measure each (arm, scenario)'s kinetic energy floor at rest
            (:func:`~reflexarm.experiments.rest_floor.rest_floor`, at the posture at detection) and compare each
            run's energy 0.5 s after detection with it (row keys ``rest_floor_*_J``, ``ke_floor_verdict``).
        detection: per arm name, a tuned detection pair (:func:`~reflexarm.experiments.tuned_detection.
            load_tuned_detection`): that arm's runs detect with its detection observer and levels, on the model
            errors they were tuned on (its ``model_seed``, when it has one, instead of ``model_seed``); arms not in
            it detect as the paper (k_o = 5 1/s, 11 Nm).
        reaction_settings: the reactions' settings (brake time, retract distance, ...; None: their defaults).

    Raises:
        ConfigError: an unknown arm or scenario, or no reaction.
    """
    bad = [s for s in scenarios if s not in SCENARIOS]
    if bad:
        raise ConfigError(f"unknown scenario {bad[0]!r}; choose from: {', '.join(SCENARIOS)}")
    if not reactions:
        raise ConfigError("no reaction to study; give one or more of: " + ", ".join(STUDY_REACTIONS))
    resolved = [a if isinstance(a, StudyArm) else study_arm(a, folder) for a in arms]
    kwargs: dict[str, Any] = {"model_error": model_error, "model_seed": model_seed, "noise": noise, "seed": seed}
    study = ReactionStudy(
        conditions={
            "model_error": 0.1 if model_error is None else model_error,
            "model_seed": model_seed,
            "noise": "paper" if noise == PAPER_NOISE else repr(noise),
            "seed": seed,
            "observer_gain_per_s": LINK_SETTING.observer_gain,
            "threshold_Nm": LINK_SETTING.threshold,
            "stiffness_Nm_per_rad": LINK_SETTING.stiffness,
        }
    )
    if reaction_settings is not None:
        study.conditions["reaction_settings"] = asdict(reaction_settings)
    tuned_of = dict(detection or {})
    if tuned_of:
        study.conditions["detection"] = {name: t.as_dict() for name, t in tuned_of.items()}
    for arm in resolved:
        tuned = tuned_of.get(arm.name)
        arm_kwargs = kwargs if tuned is None or tuned.model_seed is None else {**kwargs, "model_seed": tuned.model_seed}
        for scenario in scenarios:
            floor: RestFloor | None = None  # the same for every reaction: the runs agree up to detection
            for reaction in reactions:
                row, floor = _study_row(
                    arm, scenario, reaction, arm_kwargs, tuned, floor, rest_floors, reaction_settings
                )
                study.rows.append(row)
                if progress is not None:
                    progress(row)
    return study


#: The issue's marks on the study's figure: kinetic energy below 1 % of its value at detection within 0.5 s,
#: and no peak after detection above the level at detection (ratio 1.0).
KE_RATIO_GOAL = KE_RESIDUAL_SHARE
PEAK_RATIO_GOAL = 1.0


def reaction_measures(row: dict[str, Any]) -> dict[str, Any]:
    """The study's printed measures of one row: the contact level at detection and its peak after detection
    (|f_ext,EE| [N] for an end-effector contact, max_j |tau_ext,j| [Nm] for a link collision) and their ratio,
    the kinetic energy ratio at +0.5 s, the distance moved after detection, the peak speed over the limit,
    re-contact and the guard's verdict (None where not applicable)."""
    if row.get("contact_class") == "end_effector":
        at, peak, unit = row.get("force_at_detection_N"), row.get("peak_force_after_detection_N"), "N"
    else:
        at, peak = row.get("external_torque_at_detection_Nm"), row.get("peak_external_torque_after_detection_Nm")
        unit = "Nm"
    detected = row.get("detected_s") is not None

    def ratio(x: float | None) -> float | None:
        return None if at is None or x is None or at <= 0.0 else x / at

    return {
        "level_unit": unit,
        "level_at_detection": at,
        "peak_after_detection": peak,
        "peak_ratio": ratio(peak),
        "level_text": "-" if at is None else f"{at:.1f} -> {'-' if peak is None else f'{peak:.1f}'} {unit}",
        "ke_ratio": row.get("kinetic_energy_ratio"),
        "moved_m": row.get("moved_after_detection_m"),
        "away_m": row.get("away_at_end_m"),
        "peak_speed_ratio": row.get("peak_speed_ratio"),
        "recontact": None if not detected else ("yes" if row.get("recontact") else "no"),
        "guard": row.get("guard") if row.get("error") is None else f"error: {row['error']}",
    }


def _floor_ratio(row: dict[str, Any] | None) -> float:
    """The row's rest floor (its quantile) over its kinetic energy at detection; NaN without them."""
    floor = None if row is None else row.get("rest_floor_q95_J")
    at = None if row is None else row.get("kinetic_energy_at_detection_J")
    return float(floor) / float(at) if floor is not None and at else float("nan")


def reaction_study_figure(study: ReactionStudy) -> Figure:
    """Per scenario (columns), bars per arm grouped by reaction: the kinetic energy ratio at +0.5 s (top, log
    scale, the issue's 1 % line, each bar's rest floor over the same energy at detection as a black mark) and
    the peak after detection over the level at detection (bottom, the 1.0 line). A missing bar: no detection,
    an error, or a ratio that does not apply."""
    from matplotlib.figure import Figure

    scenarios = list(dict.fromkeys(r["scenario"] for r in study.rows)) or list(SCENARIOS)
    arms = list(dict.fromkeys(r["arm"] for r in study.rows))
    reactions = list(dict.fromkeys(r["reaction"] for r in study.rows))
    fig = Figure(figsize=(max(6.0, 3.2 * len(scenarios) + 0.6 * len(arms)), 6.5), layout="constrained")
    axes = fig.subplots(2, len(scenarios), squeeze=False, sharex="col")
    width = 0.8 / max(len(reactions), 1)
    x = np.arange(len(arms))
    by_key = {(r["arm"], r["scenario"], r["reaction"]): reaction_measures(r) for r in study.rows}
    by_row = {(r["arm"], r["scenario"], r["reaction"]): r for r in study.rows}
    for c, scenario in enumerate(scenarios):
        top, bottom = axes[0, c], axes[1, c]
        for i, reaction in enumerate(reactions):
            m = [by_key.get((a, scenario, reaction), {}) for a in arms]
            off = x + (i - (len(reactions) - 1) / 2) * width
            ke = [np.nan if v.get("ke_ratio") is None else float(v["ke_ratio"]) for v in m]
            pk = [np.nan if v.get("peak_ratio") is None else float(v["peak_ratio"]) for v in m]
            top.bar(off, ke, width, color=f"C{i}", label=reaction)
            # the rest floor over the same KE at detection: a bar down to its mark is as still as a hold gets
            fl = [_floor_ratio(by_row.get((a, scenario, reaction))) for a in arms]
            top.scatter(off, fl, marker="_", s=60, color="k", label="rest floor" if i == 0 and c == 0 else None)
            bottom.bar(off, pk, width, color=f"C{i}", label=reaction)
        top.axhline(KE_RATIO_GOAL, color="k", ls="--", lw=1, label=f"{100 * KE_RATIO_GOAL:g} % (issue 15)")
        goal = bottom.axhline(PEAK_RATIO_GOAL, color="k", ls="--", lw=1, label=f"{PEAK_RATIO_GOAL:g} (issue 15)")
        if c == 0:
            bottom.legend(handles=[goal], fontsize=7, loc="lower right")
        top.set_yscale("log")
        top.set_title(f"scenario: {scenario}", fontsize=9)
        top.set_ylabel("KE(+0.5 s) / KE(detection) [-]")
        bottom.set_ylabel("peak after / at detection [-]")
        bottom.set_xticks(x, arms, rotation=20, fontsize=7, ha="right")
        for ax in (top, bottom):
            ax.grid(alpha=0.3, axis="y", which="both")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncol=len(labels))
    cond = study.conditions
    fig.suptitle(
        f"Reactions after detection: +-{100 * float(cond.get('model_error', 0.1)):g} % model error, "
        f"noise {cond.get('noise', '?')}, seed {cond.get('seed', '?')}",
        fontsize=9,
    )
    return fig


def plot_reaction_study(study: ReactionStudy, path: str | Path) -> Path:
    """Write :func:`reaction_study_figure` as PNG at ``path`` (folders created)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    reaction_study_figure(study).savefig(p, dpi=120)
    return p
