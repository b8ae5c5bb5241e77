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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from reflexarm.errors import ConfigError
from reflexarm.experiments.collision import (
    EE_SETTINGS,
    LINK_SETTING,
    run_ee_collision,
    run_link_collision,
)
from reflexarm.experiments.collision_events import CollisionOutcome, collision_outcome, write_outcomes
from reflexarm.robots import RobotModel, load_robot
from reflexarm.sim import PAPER_NOISE, SensorNoise

__all__ = [
    "SCENARIOS",
    "STUDY_ARMS",
    "STUDY_REACTIONS",
    "ReactionStudy",
    "StudyArm",
    "run_reaction_study",
    "study_arm",
]

#: The arms of the study, by name (see :func:`study_arm`).
STUDY_ARMS = ("atlas_v5_left_arm", "panda", "iiwa14", "ur_like", "iiwa14_frictionless")

#: The reactions the study compares (issue 15); "none" (detection reported only) may be added as a baseline.
STUDY_REACTIONS = ("gravity", "brake", "retract", "compliant")

#: The contact scenarios: the demo's end-effector contact (cinderblock) and the link collision (stick).
SCENARIOS = ("demo", "link")


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


def _run_one(arm: StudyArm, scenario: str, reaction: str, kwargs: dict[str, Any]) -> CollisionOutcome:
    if scenario == "demo":
        coll_det = next(s for s in EE_SETTINGS if s.name == "Coll.Det")
        trace = run_ee_collision(
            replace(coll_det, reaction=reaction), robot=arm.robot, plant_friction=arm.plant_friction, **kwargs
        )
    else:
        trace = run_link_collision(
            setting=replace(LINK_SETTING, reaction=reaction),
            robot=arm.robot,
            plant_friction=arm.plant_friction,
            **kwargs,
        )
    return collision_outcome(trace, arm.robot, name=f"{arm.name}/{scenario}/{reaction}")


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
    for arm in resolved:
        for scenario in scenarios:
            for reaction in reactions:
                row: dict[str, Any] = {
                    "arm": arm.name,
                    "scenario": scenario,
                    "reaction": reaction,
                    "plant_friction": arm.plant_friction,
                    "error": None,
                }
                try:
                    row.update(_run_one(arm, scenario, reaction, kwargs).as_dict())
                except ConfigError as e:  # e.g. a reaction this controller does not offer (yet)
                    row["error"] = str(e)
                study.rows.append(row)
                if progress is not None:
                    progress(row)
    return study
