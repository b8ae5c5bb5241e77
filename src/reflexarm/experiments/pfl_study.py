"""The power-and-force-limiting study: several arms, regions, speeds and reactions (``reflexarm pfl``), its table
(CSV/JSON), a figure per region and a one-page HTML report."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from reflexarm.errors import ReflexArmError
from reflexarm.experiments.collision import CollisionSetting
from reflexarm.experiments.pfl import PFL_SETTING, run_motion_contact, run_region_contact
from reflexarm.experiments.pfl_motion import SampledMotion, SpeedLimitError
from reflexarm.experiments.pfl_placement import swing_motion
from reflexarm.robots import RobotModel

__all__ = [
    "CLAMP_SPEED",
    "CLAMP_STIFFNESS",
    "PFL_ARMS",
    "PFL_REGIONS",
    "PFL_SPEEDS",
    "PflStudy",
    "run_pfl_motion_study",
    "run_pfl_study",
    "safe_speeds",
    "transient_series",
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
#: An estimated safe speed this far (relative) beyond the fastest (or below the slowest) tested speed is simulated
#: (a run at that speed) rather than taken from the proportional scaling; within it, it counts as simulated [-].
CONFIRM_RTOL = 0.05
#: At most this many such runs per series (each run at the previous estimate).
CONFIRM_RUNS = 2
#: Where the estimate is beyond the joint velocity limits, the run at this share of the fastest reachable speed
#: (just inside the limit, whose check is exact) [-].
REACH_SHARE = 0.999


@dataclass
class PflStudy:
    """The study's rows (one per run, :meth:`~reflexarm.experiments.pfl.ContactResult.row` plus ``error``) and
    its conditions."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    conditions: dict[str, Any] = field(default_factory=dict)

    def select(self, **match: Any) -> list[dict[str, Any]]:
        """The rows whose fields equal ``match`` (failed runs included; they carry ``error``)."""
        return [r for r in self.rows if all(r.get(k) == v for k, v in match.items())]


def _error_row(
    arm: str,
    region: str,
    mode: str,
    reaction: str,
    speed: float | None,
    detection: bool,
    e: Exception,
    point: str = "ee",
) -> dict:
    reach = e.reachable_speed if isinstance(e, SpeedLimitError) else None
    return {
        "reachable_speed_m_s": reach,
        "arm": arm,
        "contact_point": point,
        "region": region,
        "mode": mode,
        "reaction": reaction,
        "detection": detection,
        "reference_speed_m_s": speed,
        "error": str(e),
    }


#: One run at a speed [m/s] (None: the motion's own timing) with a reaction and detection on/off: its row.
RunAt = Callable[[float | None, str, bool], dict[str, Any]]


def _run(robot: RobotModel, arm: str, region: str, speed: float, kw: dict[str, Any]) -> dict[str, Any]:
    try:
        result, _ = run_region_contact(robot, region, speed, **kw)
    except ReflexArmError as e:
        return {**_error_row(arm, region, kw["mode"], kw["reaction"], speed, kw["detection"], e), "motion": "swing"}
    return {**result.row(), "arm": arm, "error": None}


def _swing_runner(robot: RobotModel, arm: str, region: str, base: dict[str, Any]) -> RunAt:
    def run_at(v: float | None, reaction: str, detection: bool) -> dict[str, Any]:
        return _run(robot, arm, region, float(v or 0.0), {**base, "reaction": reaction, "detection": detection})

    return run_at


def _motion_runner(
    robot: RobotModel, arm: str, motion: SampledMotion, region: str, point: str, base: dict[str, Any]
) -> RunAt:
    def run_at(v: float | None, reaction: str, detection: bool) -> dict[str, Any]:
        kw = {**base, "reaction": reaction, "detection": detection}
        try:
            result, _ = run_motion_contact(robot, motion, region, v, point=point, **kw)
        except ReflexArmError as e:
            row = _error_row(arm, region, "transient", reaction, v, detection, e, point)
            return {**row, "motion": motion.name, "requested_speed_m_s": v}
        return {**result.row(), "arm": arm, "requested_speed_m_s": v, "error": None}

    return run_at


def run_pfl_motion_study(
    arm: str,
    robot: RobotModel,
    motion: SampledMotion,
    regions: Sequence[str] = PFL_REGIONS,
    speeds: Sequence[float] = PFL_SPEEDS,
    reactions: Sequence[str] = ("none", "gravity", "brake", "retract", "compliant"),
    points: Sequence[str] = ("ee",),
    *,
    setting: CollisionSetting = PFL_SETTING,
    model_error: float | None = None,
    seed: int = 0,
    confirm: bool = True,
    progress: Callable[[str], None] | None = None,
) -> PflStudy:
    """The transient study on a sampled motion (a trajectory file, an excitation): per region and contact point
    (``ee``, ``link<j>``), the region placed where that point moves fastest, the motion at its own timing and
    time-scaled so that the point's speed there is each of ``speeds`` [m/s] (a scaling that needs a joint beyond
    its velocity limit gives an error row saying so), detection off and each reaction
    (:func:`transient_series`). No clamped runs (the clamping study uses the swing)."""
    study = PflStudy(conditions=_conditions(setting, speeds, regions, reactions, model_error, seed, motion.name))
    study.conditions.update({"points": list(points), "time_scaled": True})
    base = dict(model_error=model_error, seed=seed, model_seed=seed, setting=setting, mode="transient")
    for point in points:
        for region in regions:
            if progress:
                progress(f"{arm} {point} {region}")
            run_at = _motion_runner(robot, arm, motion, region, point, base)
            study.rows += transient_series(run_at, [None, *speeds], reactions, confirm=confirm)
    return study


def _confirm(run_at: RunAt, rows: list[dict[str, Any]], reaction: str, detection: bool) -> list[dict[str, Any]]:
    """Runs at the estimated safe speed while it lies beyond the tested speeds (:data:`CONFIRM_RTOL`), at most
    :data:`CONFIRM_RUNS`; a speed the motion cannot reach within the joint velocity limits gives its error row and
    a run at the fastest speed it can reach instead (``confirmation`` True on these rows)."""
    out: list[dict[str, Any]] = []
    for _ in range(CONFIRM_RUNS):
        est = safe_speeds(rows + out)
        if not est["extrapolated"] or est["simulated_safe_speed_m_s"] is None:
            break
        row = {**run_at(float(est["simulated_safe_speed_m_s"]), reaction, detection), "confirmation": True}
        out.append(row)
        reach = row.get("reachable_speed_m_s")
        if row.get("error"):
            tested = [r["reference_speed_m_s"] for r in rows + out if r.get("error") is None]
            if reach and (not tested or reach > max(tested) * (1.0 + CONFIRM_RTOL)):
                out.append({**run_at(REACH_SHARE * reach, reaction, detection), "confirmation": True})
            break
    return out


def transient_series(
    run_at: RunAt, speeds: Sequence[float | None], reactions: Sequence[str], *, confirm: bool = True
) -> list[dict[str, Any]]:
    """The transient runs of one (arm, region, point): each speed with detection off and with each reaction;
    then, per series, runs at the estimated safe speed where it lies beyond the tested speeds (:func:`_confirm`)."""
    rows: list[dict[str, Any]] = []
    series = [("none", False)] + [(reaction, True) for reaction in reactions]
    for speed in speeds:
        rows += [run_at(speed, reaction, detection) for reaction, detection in series]
    if confirm:
        for reaction, detection in series:
            mine = [r for r in rows if r.get("reaction") == reaction and r.get("detection") == detection]
            rows += _confirm(run_at, mine, reaction, detection)
    return rows


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
    confirm: bool = True,
    points: Sequence[str] = ("ee",),
    progress: Callable[[str], None] | None = None,
) -> PflStudy:
    """Per arm and region: the transient contact at each speed with detection off (the analytic check) and with
    each reaction (:func:`transient_series`; ``confirm``: also simulate the estimated safe speed where it lies
    beyond the tested speeds and the swing reaches it); the clamped contact at ``clamp_speed`` with each
    reaction (stiffness ``clamp_stiffness``). ``points`` other than ``ee`` (``link<j>``): the same transient
    series with the region where that point moves fastest along the swing, the swing time-scaled so that the
    point's speed there is each speed (:func:`run_pfl_motion_study`). A run that cannot be made (a speed the arm
    cannot reach, a region it cannot place) gives a row whose ``error`` says why."""
    study = PflStudy(conditions=_conditions(setting, speeds, regions, reactions, model_error, seed, "swing"))
    study.conditions.update({"clamp_speed_m_s": clamp_speed, "clamp_stiffness_Nm_per_rad": clamp_stiffness})
    study.conditions["points"] = list(points)
    clamp_setting = replace(setting, stiffness=clamp_stiffness)
    for arm, robot in arms:
        for region in regions:
            if progress:
                progress(f"{arm} {region}")
            base = dict(model_error=model_error, seed=seed, model_seed=seed, setting=setting, mode="transient")
            study.rows += transient_series(_swing_runner(robot, arm, region, base), speeds, reactions, confirm=confirm)
            for point in [p for p in points if p != "ee"]:
                if progress:
                    progress(f"{arm} {point} {region}")
                run_at = _motion_runner(robot, arm, swing_motion(robot), region, point, base)
                study.rows += transient_series(run_at, speeds, reactions, confirm=confirm)
            for reaction in reactions:
                kw = {**base, "mode": "clamped", "setting": clamp_setting, "reaction": reaction, "detection": True}
                study.rows.append(_run(robot, arm, region, clamp_speed, kw))
    return study


def _conditions(
    setting: CollisionSetting,
    speeds: Sequence[float],
    regions: Sequence[str],
    reactions: Sequence[str],
    model_error: float | None,
    seed: int,
    motion: str,
) -> dict[str, Any]:
    return {
        "motion": motion,
        "setting": {k: v for k, v in vars(setting).items()},
        "speeds_m_s": list(speeds),
        "regions": list(regions),
        "reactions": list(reactions),
        "model_error": model_error,
        "seed": seed,
    }


def safe_speeds(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """For the transient rows of one (arm, region, point, reaction or detection off): the largest tested speed
    whose simulated peak stays within F_T, and the speed at which the peak would reach F_T if it scales with the
    speed as F = v sqrt(mu k) does (the smallest v F_T / F_peak over the tested speeds; ``extrapolated``
    True when that speed lies outside the tested range by more than :data:`CONFIRM_RTOL`) [m/s]."""
    ok = [r for r in rows if r.get("error") is None and r.get("peak_force_N") is not None]
    if not ok:
        return {"largest_tested_safe_speed_m_s": None, "simulated_safe_speed_m_s": None, "extrapolated": None}
    safe = [r["reference_speed_m_s"] for r in ok if r["peak_force_N"] <= r["F_T_N"]]
    est = min(r["approach_speed_m_s"] * r["F_T_N"] / r["peak_force_N"] for r in ok)
    tested = [r["reference_speed_m_s"] for r in ok]
    lo, hi = min(tested) * (1.0 - CONFIRM_RTOL), max(tested) * (1.0 + CONFIRM_RTOL)
    return {
        "largest_tested_safe_speed_m_s": max(safe) if safe else None,
        "simulated_safe_speed_m_s": est,
        "extrapolated": not (lo <= est <= hi) or math.isnan(est),
    }
