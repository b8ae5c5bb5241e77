"""The power-and-force-limiting study: several arms, regions, speeds and reactions (``reflexarm pfl``), its table
(CSV/JSON), a figure per region and a one-page HTML report."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from reflexarm.errors import ReflexArmError
from reflexarm.experiments.collision import CollisionSetting
from reflexarm.experiments.pfl import PFL_SETTING, run_region_contact
from reflexarm.robots import RobotModel

__all__ = [
    "CLAMP_SPEED",
    "CLAMP_STIFFNESS",
    "PFL_ARMS",
    "PFL_REGIONS",
    "PFL_SPEEDS",
    "PflStudy",
    "run_pfl_study",
    "safe_speeds",
]

#: The arms of the study (names of :func:`~reflexarm.experiments.reaction_study.study_arm`).
PFL_ARMS = ("panda", "iiwa14", "ur_like", "atlas_v5_left_arm")
#: The regions of the issue's table.
PFL_REGIONS = ("chest", "abdomen", "hand", "upper_arm", "skull")
#: Peak end-effector speeds of the swing [m/s].
PFL_SPEEDS = (0.25, 0.5, 0.75)
#: The clamping runs: speed [m/s] and joint stiffness [Nm/rad] (the demo's Coll.Det stiffness: a stiff arm
#: pressing on a clamped region is the case a reaction has to resolve).
CLAMP_SPEED = 0.25
CLAMP_STIFFNESS = 300.0


@dataclass
class PflStudy:
    """The study's rows (one per run, :meth:`~reflexarm.experiments.pfl.ContactResult.row` plus ``error``) and
    its conditions."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    conditions: dict[str, Any] = field(default_factory=dict)

    def select(self, **match: Any) -> list[dict[str, Any]]:
        """The rows whose fields equal ``match`` (failed runs included; they carry ``error``)."""
        return [r for r in self.rows if all(r.get(k) == v for k, v in match.items())]


def _error_row(arm: str, region: str, mode: str, reaction: str, speed: float, detection: bool, e: Exception) -> dict:
    return {
        "arm": arm,
        "region": region,
        "mode": mode,
        "reaction": reaction,
        "detection": detection,
        "reference_speed_m_s": speed,
        "error": str(e),
    }


def _run(robot: RobotModel, arm: str, region: str, speed: float, kw: dict[str, Any]) -> dict[str, Any]:
    try:
        result, _ = run_region_contact(robot, region, speed, **kw)
    except ReflexArmError as e:
        return _error_row(arm, region, kw["mode"], kw["reaction"], speed, kw["detection"], e)
    return {**result.row(), "arm": arm, "error": None}


def run_pfl_study(
    arms: Sequence[tuple[str, RobotModel]],
    regions: Sequence[str] = PFL_REGIONS,
    speeds: Sequence[float] = PFL_SPEEDS,
    reactions: Sequence[str] = ("none", "gravity", "brake", "retract", "compliant"),
    *,
    clamp_speed: float = CLAMP_SPEED,
    setting: CollisionSetting = PFL_SETTING,
    clamp_stiffness: float = CLAMP_STIFFNESS,
    model_error: float | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> PflStudy:
    """Per arm and region: the transient contact at each speed with detection off (the analytic check) and with
    each reaction; the clamped contact at ``clamp_speed`` with each reaction (stiffness ``clamp_stiffness``).
    A run that cannot be made (a speed the arm cannot reach, a region it cannot place) gives a row whose
    ``error`` says why."""
    study = PflStudy(
        conditions={
            "setting": {k: v for k, v in vars(setting).items()},
            "clamp_speed_m_s": clamp_speed,
            "clamp_stiffness_Nm_per_rad": clamp_stiffness,
            "speeds_m_s": list(speeds),
            "regions": list(regions),
            "reactions": list(reactions),
            "model_error": model_error,
            "seed": seed,
        }
    )
    clamp_setting = replace(setting, stiffness=clamp_stiffness)
    for arm, robot in arms:
        for region in regions:
            if progress:
                progress(f"{arm} {region}")
            base = dict(model_error=model_error, seed=seed, model_seed=seed, setting=setting, mode="transient")
            for speed in speeds:
                study.rows.append(_run(robot, arm, region, speed, {**base, "reaction": "none", "detection": False}))
                for reaction in reactions:
                    study.rows.append(
                        _run(robot, arm, region, speed, {**base, "reaction": reaction, "detection": True})
                    )
            for reaction in reactions:
                kw = {**base, "mode": "clamped", "setting": clamp_setting, "reaction": reaction, "detection": True}
                study.rows.append(_run(robot, arm, region, clamp_speed, kw))
    return study


def safe_speeds(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """For the transient rows of one (arm, region, reaction or detection off): the largest tested speed whose
    simulated peak stays within F_T, and the speed at which the peak would reach F_T if it scales with the
    speed as F = v sqrt(mu k) does (the smallest v F_T / F_peak over the tested speeds; ``extrapolated``
    True when that speed lies outside the tested range) [m/s]."""
    ok = [r for r in rows if r.get("error") is None and r.get("peak_force_N") is not None]
    if not ok:
        return {"largest_tested_safe_speed_m_s": None, "simulated_safe_speed_m_s": None, "extrapolated": None}
    safe = [r["reference_speed_m_s"] for r in ok if r["peak_force_N"] <= r["F_T_N"]]
    est = min(r["approach_speed_m_s"] * r["F_T_N"] / r["peak_force_N"] for r in ok)
    tested = [r["reference_speed_m_s"] for r in ok]
    return {
        "largest_tested_safe_speed_m_s": max(safe) if safe else None,
        "simulated_safe_speed_m_s": est,
        "extrapolated": not (min(tested) <= est <= max(tested)) or math.isnan(est),
    }
