"""Check proposed thresholds where they will be used: a held-out free-motion run and the demo collision.

On the built-in Atlas arm (simulation): a free-motion run with other noise (and optionally another motion)
than the tuning logs, detected online at the proposed zeta (reaction "none", so detection does not change
the motion; the controller's flag latches, so online there is at most one alarm), and the separate alarms
counted offline on the same run's replayed residual at any levels (:func:`count_alarms`); then the demo's
cinderblock collision (Figs. 7-8, Coll.Det with reaction (13)) detected with the proposed zeta.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.tuning.free_motion_log import record_free_motion_log
from reflexarm.tuning.replay import ObserverSettings, replay_residual

__all__ = ["count_alarms", "demo_collision_with", "heldout_free_motion"]


def count_alarms(residual: npt.ArrayLike, levels: npt.ArrayLike, dt: float, gap_s: float) -> dict[str, object]:
    """Separate alarms of the arm at per-joint ``levels`` [Nm]: excursions of "any |r_j| > level_j" closer than
    ``gap_s`` [s] are one alarm (as in the tail fit). Returns the arm's count, the count per joint
    (1-based keys) and the times of the arm's alarms [s from the start]."""
    r = np.abs(np.asarray(residual, dtype=float))
    lv = np.broadcast_to(np.asarray(levels, dtype=float), (r.shape[1],))
    if not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a positive period [s]; got {dt!r}")
    gap = int(math.ceil(gap_s / dt - 1e-9))

    def starts(over: np.ndarray) -> np.ndarray:
        idx = np.flatnonzero(over)
        if idx.size == 0:
            return idx
        return idx[np.r_[0, np.flatnonzero(np.diff(idx) > gap + 1) + 1]]

    over = r > lv
    arm = starts(over.any(axis=1))
    return {
        "alarms": int(arm.size),
        "alarms_per_joint": {str(j + 1): int(starts(over[:, j]).size) for j in range(r.shape[1])},
        "alarm_times_s": [float(k * dt) for k in arm[:20]],
    }


def heldout_free_motion(
    zeta: npt.ArrayLike,
    model: RobotModel,
    *,
    duration: float = 600.0,
    seed: int = 100,
    motion: str = "hydraulic",
    compare: dict[str, npt.ArrayLike] | None = None,
    settings: ObserverSettings | None = None,
    gap_s: float | None = None,
    progress: bool = False,
) -> dict[str, object]:
    """A held-out free-motion run detected online at ``zeta``; offline alarm counts at ``zeta`` and at the
    levels of ``compare`` (name -> levels, e.g. ``{"11 Nm": 11.0, "contact": proposal.contact}``).

    ``model`` is the controller's model of the run (the model the thresholds were tuned with), its observers those
    of ``settings`` online and in the replay (the same residual: ``replay_vs_online_max_abs_residual_Nm``);
    ``gap_s``: the declustering gap [s] (default ``settings.declustering_gap``: 5 x (1/k_o + 1/K_f), the
    detector's time scale; 1/K_f with a second stage in ``settings`` only).
    """
    s = settings or ObserverSettings()
    run = record_free_motion_log(
        duration, motion=motion, model=model, seed=seed, threshold=zeta, settings=s, progress=progress,
    )  # fmt: skip
    rep = replay_residual(run.log, model, s)
    gap = s.declustering_gap if gap_s is None else gap_s
    out: dict[str, object] = {"online": run.as_dict(), "motion": motion, "noise_seed": seed, "gap_s": gap}
    levels: dict[str, npt.ArrayLike] = {"proposed": zeta, **(compare or {})}
    out["offline"] = {name: count_alarms(rep.residual, lv, rep.dt, gap) for name, lv in levels.items()}
    out["replay_vs_online_max_abs_residual_Nm"] = float(
        np.max(np.abs(np.abs(rep.residual).max(axis=0) - run.max_abs_residual))
    )
    return out


def demo_collision_with(
    thresholds: dict[str, Sequence[float] | float], model: RobotModel, *, seed: int = 0
) -> list[dict[str, object]]:
    """The demo's Coll.Det run (cinderblock, k = 300 Nm/rad, k_o = 5 1/s, reaction (13)) once per named
    threshold (scalar or per joint); each row: the summary of
    :func:`~reflexarm.experiments.collision.summarize_ee_collision` with the threshold's name."""
    from reflexarm.experiments.collision import CollisionSetting, run_ee_collision, summarize_ee_collision

    rows = []
    for name, zeta in thresholds.items():
        arr = np.asarray(zeta, dtype=float).reshape(-1)
        value = float(arr[0]) if np.ndim(zeta) == 0 else tuple(float(v) for v in arr)
        setting = CollisionSetting("Coll.Det", stiffness=300.0, observer_gain=5.0, threshold=value)  # type: ignore[arg-type]
        trace = run_ee_collision(setting, model=model, seed=seed)
        row = summarize_ee_collision(trace)
        joints = np.flatnonzero(trace.collided.any(axis=0))
        first = trace.first_time(trace.collision)
        at_first: list[int] = (
            np.flatnonzero(trace.collided[np.flatnonzero(trace.collision)[0]]).tolist() if first is not None else []
        )
        row.update(
            {
                "threshold": name,
                "first_detected_joints": [int(j) + 1 for j in at_first],
                "joints_over_threshold": [int(j) + 1 for j in joints],
            }
        )
        rows.append(row)
    return rows
