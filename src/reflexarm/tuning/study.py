"""Collision thresholds from the user's own free-motion logs: two levels per joint and what they imply.

:func:`tune_thresholds` replays the observer on the logs (:func:`~reflexarm.tuning.replay_residual`),
fits the tail of each joint's |residual| (:mod:`reflexarm.tuning.tail`: excursions declustered with a gap
of 5 x (1/k_o + 1/K_f), 1/K_f with a second stage only; the 30 largest above u, an exponential tail by
default, :data:`DEFAULT_METHOD`) and proposes, as libfranka does, two levels per joint:

* **collision** zeta_j: false alarms at the user's rate R [1/h] for the whole arm;
* **contact** level: a lower one at the rate R_c [1/h] (default 60, one per minute), for logging or a soft
  reaction.

Detection (12) fires when *any* joint crosses, so the arm's rate is the sum of the joints' rates; each
joint gets R / n (Bonferroni's split; the arm's rate is then at most R). A level at a rate whose return
period n / R exceeds :data:`MAX_EXTRAPOLATION` times the logs' span is an extrapolation the tail cannot
carry: refused (:class:`LogTooShortError`, with the minimum duration) unless ``allow_extrapolation``.

For each level the detection delay of a step of external torque s [Nm] at the joint follows from the
observer's first-order response (8), r(t) = b + s (1 - exp(-t / T_o)) with T_o = -dt / ln(1 - k_o dt)
(the Euler observer's time constant, 1/k_o to 0.3 %; T_o = 1/k_o for the exact form): the residual crosses
zeta at

    t_d = -T_o ln(1 - (zeta - b) / s)     (never if s <= zeta - b),

given for b = 0 ("nominal") and b = -q95 ("unfavourable": the residual's 95th percentile of |r| in the
logs, e.g. friction, pointing against the step); with a second stage of gain K_f on the residual
(:attr:`~reflexarm.tuning.ObserverSettings.detection_filter_gain`) t_d is the root of the cascade's step
response (:func:`~reflexarm.tuning.detection_delay`); :func:`~reflexarm.tuning.force_step_delays` does the same
for a force at the end effector. Each level is checked against the logs: crossed more often than its
rate allows (:data:`CONSISTENCY_QUANTILE` of the Poisson count), it is flagged with a warning.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import poisson

from reflexarm.detect.coverage import JointCoverage
from reflexarm.errors import ConfigError, DataError
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel
from reflexarm.tuning._log_check import count_crossings, lowest_level_crossed_at_most
from reflexarm.tuning.defaults import DEFAULT_CONTACT_RATE, DEFAULT_METHOD, DEFAULT_RATE
from reflexarm.tuning.delays import detection_delay, force_step_delays
from reflexarm.tuning.replay import (
    ObserverSettings,
    ResidualReplay,
    ThresholdWarning,
    load_free_motion_log,
    replay_residual,
)
from reflexarm.tuning.tail import TailFit, fit_tail

__all__ = [
    "DEFAULT_CONTACT_RATE",
    "DEFAULT_METHOD",
    "DEFAULT_RATE",
    "MAX_EXTRAPOLATION",
    "JointThresholds",
    "LogTooShortError",
    "ThresholdProposal",
    "tune_thresholds",
]

#: Largest return period of a level, in multiples of the logs' span: a tail fit is trusted to about an
#: order of magnitude beyond the data (Coles 2001, Sec. 4.4: return-level intervals widen quickly past it).
MAX_EXTRAPOLATION = 10.0
#: A level is flagged when the logs cross it more often than this quantile of the Poisson count its rate
#: predicts over the logs' span (1 % false flags on a well-fitted tail).
CONSISTENCY_QUANTILE = 0.99


class LogTooShortError(DataError):
    """The logs are too short for the asked rate.

    Attributes:
        duration_s: the logs' span [s]; minimum_s: the span the rate needs [s]; rate_per_hour: the asked
        rate for the arm [1/h]; level: "collision" or "contact".
    """

    def __init__(self, duration_s: float, minimum_s: float, rate_per_hour: float, level: str) -> None:
        self.duration_s, self.minimum_s, self.rate_per_hour, self.level = duration_s, minimum_s, rate_per_hour, level
        super().__init__(
            f"the {level} level at {rate_per_hour:g} false alarms per hour needs at least {minimum_s / 60:.1f} min of "
            f"free-motion log ({MAX_EXTRAPOLATION:g}x shorter than its per-joint return period); got "
            f"{duration_s / 60:.1f} min (record more, ask for a higher rate, or allow the extrapolation)"
        )


@dataclass(frozen=True)
class JointThresholds:
    """The proposal for one joint (0-based ``joint`` in Python; printed 1-based)."""

    joint: int
    name: str
    collision: float
    collision_interval: tuple[float, float]
    contact: float
    contact_interval: tuple[float, float]
    fit: TailFit
    q95: float
    delays: dict[str, float | None] = field(default_factory=dict)
    in_logs: dict[str, float] = field(default_factory=dict)

    def row(self) -> dict[str, object]:
        """A flat row for tables and CSV (joint 1-based)."""
        row: dict[str, object] = {
            "joint": self.joint + 1,
            "name": self.name,
            "collision_Nm": self.collision,
            "collision_lo_Nm": self.collision_interval[0],
            "collision_hi_Nm": self.collision_interval[1],
            "contact_Nm": self.contact,
            "contact_lo_Nm": self.contact_interval[0],
            "contact_hi_Nm": self.contact_interval[1],
            "max_abs_residual_Nm": self.fit.x_max,
            "q95_abs_residual_Nm": self.q95,
            "u_Nm": self.fit.u,
            "xi": self.fit.xi,
            "sigma_Nm": self.fit.sigma,
            "clusters_above_u": self.fit.n_clusters,
        }
        row.update(self.delays)
        row.update(self.in_logs)
        return row


@dataclass
class ThresholdProposal:
    """What :func:`tune_thresholds` returns: per-joint levels, the settings and logs they came from."""

    joints: list[JointThresholds]
    rate_per_hour: float
    contact_rate_per_hour: float
    step_torque: float
    settings: ObserverSettings
    time_constant: float
    duration_s: float
    sources: list[str]
    fault_ticks: int
    method: str
    replays: list[ResidualReplay] = field(default_factory=list, repr=False)
    notes: list[str] = field(default_factory=list)
    step_force: float | None = None
    force_posture: list[float] | None = None
    force_steps: dict[str, list[dict[str, object]]] = field(default_factory=dict)
    #: (k_o, zeta) pairs of :func:`~reflexarm.tuning.propose_detection_pairs` (its ``as_dict``), or None
    detection_pairs: dict[str, object] | None = None
    #: what the logs covered of each joint's range and speed (None for residuals given without their logs)
    coverage: list[JointCoverage] | None = None

    @property
    def unmoved(self) -> list[int]:
        """0-based joints that did not move in the logs (their levels describe noise at rest)."""
        return [] if self.coverage is None else [c.joint for c in self.coverage if not c.moved]

    @property
    def collision(self) -> np.ndarray:
        """zeta per joint [Nm] (model order) for :class:`~reflexarm.control.Controller`'s ``threshold``."""
        return np.array([j.collision for j in self.joints])

    @property
    def contact(self) -> np.ndarray:
        """Contact level per joint [Nm]."""
        return np.array([j.contact for j in self.joints])

    def rows(self) -> list[dict[str, object]]:
        """One row per joint (1-based), with what the logs covered of it when known."""
        rows = [j.row() for j in self.joints]
        for row, c in zip(rows, self.coverage or [], strict=False):
            row.update(moved=c.moved, range_share=c.range_share, speed_max=c.speed)
        return rows

    def as_dict(self) -> dict[str, object]:
        """JSON-ready summary (joints 1-based), with the method and the formulas stated."""
        return {
            "method": {
                "tail": f"{self.method}: peaks over threshold of the declustered |residual| per joint "
                "(clusters closer than the gap are one alarm; u below the 30 largest), exponential tail (shape 0, "
                "scale = mean excess) or generalized Pareto by probability-weighted moments, levels at the "
                "per-joint rate; 90 % bootstrap interval",
                "per_joint_rate": "the arm's rate split evenly over the joints (rate / n)",
                "delay": "t_d = -T_o ln(1 - (zeta - b) / s), T_o = -dt / ln(1 - k_o dt) (Euler) or 1 / k_o (exact); "
                "b = 0 (nominal) or -q95 of |r| (unfavourable); with a second stage (detection_filter_gain K_f) "
                "the root of b + s step(t) = zeta, step(t) = 1 - (T_o e^(-t/T_o) - T_f e^(-t/T_f)) / (T_o - T_f)",
            },
            "rate_per_hour": self.rate_per_hour,
            "contact_rate_per_hour": self.contact_rate_per_hour,
            "per_joint_rate_per_hour": self.rate_per_hour / len(self.joints),
            "step_torque_Nm": self.step_torque,
            "observer": self.settings.as_dict(),
            "time_constant_s": self.time_constant,
            "filter_time_constant_s": self.settings.filter_time_constant,
            "logs": self.sources,
            "duration_s": self.duration_s,
            "fault_ticks": self.fault_ticks,
            "collision_Nm": [float(v) for v in self.collision],
            "contact_Nm": [float(v) for v in self.contact],
            "joints": self.rows(),
            "fits": {str(j.joint + 1): j.fit.as_dict() for j in self.joints},
            "force_step": None
            if self.step_force is None
            else {
                "force_N": self.step_force,
                "posture_rad": self.force_posture,
                "note": "tau = J_v(q)^T F at the first log's median posture; the first joint to cross, b = 0",
                "levels": self.force_steps,
            },
            "notes": list(self.notes),
            "coverage": None if self.coverage is None else [c.as_dict() for c in self.coverage],
            **({} if self.detection_pairs is None else {"detection_pairs": self.detection_pairs}),
        }


def _check_rate(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name} must be a positive number of false alarms per hour; got {value!r}")
    return float(value)


def _replay_logs(
    log_list: Sequence[RobotLog | ResidualReplay | str | os.PathLike[str]],
    robot: RobotModel,
    settings: ObserverSettings,
    read: Callable[[str | os.PathLike[str]], RobotLog],
) -> tuple[list[ResidualReplay], np.ndarray | None, list[JointCoverage] | None, list[str]]:
    """The residual of each log (one-sample glitches repaired first), the first log's median posture, the logs'
    coverage (None when some item is a residual without its log) and the notes on repaired glitches."""
    from reflexarm.detect.coverage import measure_coverage
    from reflexarm.detect.glitches import repair_glitches

    replays, q_parts, dq_parts, notes = [], [], [], []
    posture: np.ndarray | None = None
    for item in log_list:
        if isinstance(item, ResidualReplay):
            replays.append(item)
            continue
        log = item if isinstance(item, RobotLog) else read(item)
        if posture is None:
            posture = np.median(log.q, axis=0)
        log, glitches = repair_glitches(log)
        if glitches:
            where = ", ".join(f"joint {g.joint + 1} {g.kind} at {g.t:.3f} s" for g in glitches[:5])
            notes.append(f"{log.source}: {len(glitches)} one-sample glitch(es) repaired before the replay (they "
                         f"set no level): {where}{' ...' if len(glitches) > 5 else ''}")  # fmt: skip
        q_parts.append(log.q)
        dq_parts.append(log.dq)
        replays.append(replay_residual(log, robot, settings))
        del log
    coverage = measure_coverage(q_parts, dq_parts, robot) if len(q_parts) == len(replays) else None
    if coverage is not None and not all(c.moved for c in coverage):
        still = [c for c in coverage if not c.moved]
        msg = (f"joint(s) {', '.join(f'{c.joint + 1} ({c.name})' for c in still)} did not move in the logs: their "
               "levels describe the noise of a joint at rest and would raise false alarms on a motion that moves "
               "them (record motion of every joint)")  # fmt: skip
        warnings.warn(msg, ThresholdWarning, stacklevel=3)
        notes.append(msg)
    return replays, posture, coverage, notes


def _check_arguments(
    rate_per_hour: float, contact_rate_per_hour: float, step_torque: float, step_force: float | None
) -> tuple[float, float]:
    """The checked (collision, contact) rates [1/h]; a bad rate, step torque or step force is a ConfigError."""
    rate = _check_rate(rate_per_hour, "rate_per_hour")
    contact_rate = _check_rate(contact_rate_per_hour, "contact_rate_per_hour")
    if contact_rate <= rate:
        raise ConfigError(
            f"the contact level needs a higher false-alarm rate than the collision level ({rate:g}/h); "
            f"got contact_rate_per_hour={contact_rate:g}"
        )
    if not (isinstance(step_torque, (int, float)) and math.isfinite(step_torque) and step_torque > 0):
        raise ConfigError(f"step_torque must be a positive torque [Nm]; got {step_torque!r}")
    if step_force is not None and not (
        isinstance(step_force, (int, float)) and math.isfinite(step_force) and step_force > 0
    ):
        raise ConfigError(f"step_force must be a positive force [N]; got {step_force!r}")
    return rate, contact_rate


def _check_duration(duration: float, n: int, rates: dict[str, float], allow: bool, notes: list[str]) -> None:
    """Refuse (LogTooShortError) a level whose per-joint return period exceeds MAX_EXTRAPOLATION x the logs' span
    ``duration`` [s], or with ``allow`` warn and note it (``rates``: the arm's rate per level [1/h])."""
    for level, r_arm in rates.items():
        minimum = n / r_arm * 3600.0 / MAX_EXTRAPOLATION
        if duration < minimum:
            err = LogTooShortError(duration, minimum, r_arm, level)
            if not allow:
                raise err
            warnings.warn(f"{err} -- extrapolating as asked", ThresholdWarning, stacklevel=3)
            notes.append(f"{level} level extrapolated: {err}")


def _joint_thresholds(
    j: int,
    name: str,
    parts: list[np.ndarray],
    dt: float,
    fit: TailFit,
    rates: dict[str, float],
    delay: tuple[float, float, float | None],
    boot: tuple[int, int],
    notes: list[str],
) -> JointThresholds:
    """One joint's two levels at their per-joint ``rates`` [1/h] from the fitted tail of its |residual| ``parts``
    (period ``dt`` [s]), each raised when the logs
    cross it more often than its rate allows (a warning, noted in ``notes``), with the delays of a step
    (``delay``: step torque [Nm], the observer's and the second stage's time constants [s], the latter None
    without one) and ``boot``: (bootstrap draws, seed) of the intervals."""
    step_torque, time_constant, t_f = delay
    q95 = float(np.quantile(np.concatenate(parts), 0.95))
    delays: dict[str, float | None] = {}
    in_logs: dict[str, float] = {}
    levels = {level: fit.level(r) for level, r in rates.items()}
    for level, zeta in list(levels.items()):
        counted, expected = count_crossings(parts, zeta, dt, fit)
        if counted > poisson.ppf(CONSISTENCY_QUANTILE, expected):
            raised = lowest_level_crossed_at_most(
                parts, zeta, dt, fit, int(poisson.ppf(CONSISTENCY_QUANTILE, expected))
            )
            msg = (
                f"joint {j + 1} ({name}): the logs cross the {level} level {zeta:.4g} Nm {counted} "
                f"times where its rate predicts {expected:.2g}: the fitted tail misses the largest excursions; "
                f"raised to {raised:.4g} Nm, the lowest level the logs cross no more often than that allows "
                "(record more free motion for a fitted level)"
            )
            warnings.warn(msg, ThresholdWarning, stacklevel=4)  # _fit_joints -> tune_thresholds -> its caller
            notes.append(msg)
            in_logs[f"{level}_fitted_Nm"] = zeta
            levels[level] = zeta = raised
            counted = count_crossings(parts, zeta, dt, fit)[0]
        in_logs[f"{level}_alarms_in_logs"], in_logs[f"{level}_alarms_expected"] = counted, expected
        delays[f"{level}_delay_s"] = detection_delay(zeta, step_torque, time_constant, filter_time_constant=t_f)
        delays[f"{level}_delay_unfavourable_s"] = detection_delay(zeta, step_torque, time_constant, -q95, t_f)
    n_boot, seed = boot
    return JointThresholds(
        joint=j,
        name=name,
        collision=levels["collision"],
        collision_interval=fit.level_interval(rates["collision"], n_boot=n_boot, seed=seed),
        contact=levels["contact"],
        contact_interval=fit.level_interval(rates["contact"], n_boot=n_boot, seed=seed),
        fit=fit,
        q95=q95,
        delays=delays,
        in_logs=in_logs,
    )


def tune_thresholds(
    logs: RobotLog | str | os.PathLike[str] | Sequence[RobotLog | ResidualReplay | str | os.PathLike[str]],
    robot: RobotModel,
    *,
    settings: ObserverSettings | None = None,
    rate_per_hour: float = DEFAULT_RATE,
    contact_rate_per_hour: float = DEFAULT_CONTACT_RATE,
    step_torque: float = 30.0,
    step_force: float | None = None,
    method: str = DEFAULT_METHOD,
    gap_s: float | None = None,
    allow_extrapolation: bool = False,
    n_boot: int = 200,
    seed: int = 0,
    load: Callable[[str | os.PathLike[str]], RobotLog] | None = None,
) -> ThresholdProposal:
    """Propose collision and contact levels per joint from free-motion logs (module docstring).

    Args:
        logs: one or more free-motion logs of the arm (no contact), pooled: :class:`RobotLog` objects or
            files (read one at a time by :func:`~reflexarm.tuning.load_free_motion_log`, so only their
            residuals stay in memory), or residuals already computed (:class:`ResidualReplay`, e.g.
            :func:`~reflexarm.tuning.recorded_residual`), used as they are.
        robot: the controller's model (identified, else the nominal one).
        settings: the observer settings the user runs.
        rate_per_hour: false alarms per hour of the collision level, for the whole arm.
        contact_rate_per_hour: the same for the contact level (must be higher).
        step_torque: size of the external torque step [Nm] whose detection delay is reported.
        step_force: if given, the delay of a force step of this size [N] at the end effector along the base
            axes, mapped by J_v^T at the first log's median posture (:func:`~reflexarm.tuning.force_step_delays`).
        method: tail model, "exponential" (default, :data:`DEFAULT_METHOD`) or "gpd".
        gap_s: declustering gap [s] (default ``settings.declustering_gap``, 5 x (1/k_o + 1/K_f), 1/K_f with a stage).
        allow_extrapolation: warn instead of raising when the logs are too short for a rate.
        n_boot, seed: bootstrap draws and their seed for the intervals.
        load: reads a log file given by path (default :func:`~reflexarm.tuning.load_free_motion_log`).

    Raises:
        ConfigError: bad rates (contact not above collision), step, or settings.
        LogTooShortError: the logs are too short for a rate (unless ``allow_extrapolation``).
        DataError: logs with different periods, or too few excursions to fit a tail.
    """
    s = settings or ObserverSettings()
    rate, contact_rate = _check_arguments(rate_per_hour, contact_rate_per_hour, step_torque, step_force)
    log_list = [logs] if isinstance(logs, (RobotLog, str, os.PathLike)) else list(logs)
    if not log_list:
        raise ConfigError("no free-motion log given")
    read = load or (lambda path: load_free_motion_log(path, robot))
    replays, posture, coverage, notes = _replay_logs(log_list, robot, s, read)
    dt = _common_period(replays)
    time_constant = s.time_constant(dt)
    gap = s.declustering_gap if gap_s is None else float(gap_s)
    duration = sum(r.duration for r in replays)
    arm_rates = {"collision": rate, "contact": contact_rate}
    _check_duration(duration, robot.n, arm_rates, allow_extrapolation, notes)
    delay = (step_torque, time_constant, s.filter_time_constant)
    joints = _fit_joints(replays, robot, dt, gap, method, arm_rates, delay, (n_boot, seed), notes)
    proposal = ThresholdProposal(
        joints=joints,
        rate_per_hour=rate,
        contact_rate_per_hour=contact_rate,
        step_torque=float(step_torque),
        settings=s,
        time_constant=time_constant,
        duration_s=duration,
        sources=[r.source for r in replays],
        fault_ticks=sum(r.fault_ticks for r in replays),
        method=method,
        replays=replays,
        notes=notes,
        coverage=coverage,
    )
    if step_force is not None and posture is not None:
        _add_force_steps(proposal, robot, posture, step_force, delay[1:])
    return proposal


def _common_period(replays: list[ResidualReplay]) -> float:
    """The sample period [s] the replays share (to 0.1 %); logs of different periods are a DataError."""
    dt = replays[0].dt
    for r in replays[1:]:
        if abs(r.dt - dt) > 1e-3 * dt:
            raise DataError(
                f"logs of different periods cannot be pooled: {replays[0].source} {dt:g} s, {r.source} {r.dt:g} s"
            )
    return dt


def _fit_joints(
    replays: list[ResidualReplay],
    robot: RobotModel,
    dt: float,
    gap: float,
    method: str,
    arm_rates: dict[str, float],
    delay: tuple[float, float, float | None],
    boot: tuple[int, int],
    notes: list[str],
) -> list[JointThresholds]:
    """Each joint's tail fit of its pooled |residual| and its two levels at its share 1/n of the arm's rates
    ``arm_rates`` [1/h] (``delay``: step torque [Nm], time constants [s]; ``boot``: bootstrap draws and the
    first joint's seed, the next joints' counted on from it)."""
    n = robot.n
    n_boot, seed = boot
    joints = []
    for j in range(n):
        parts = [np.abs(r.residual[:, j]) for r in replays]
        try:
            fit = fit_tail(parts, dt, gap_s=gap, method=method)
        except DataError as e:
            raise DataError(f"joint {j + 1} ({robot.joint_names[j]}): {e}") from e
        rates = {"collision": arm_rates["collision"] / n, "contact": arm_rates["contact"] / n}
        name = robot.joint_names[j]
        joints.append(_joint_thresholds(j, name, parts, dt, fit, rates, delay, (n_boot, seed + j), notes))
    return joints


def _add_force_steps(
    proposal: ThresholdProposal,
    robot: RobotModel,
    posture: np.ndarray,
    step_force: float,
    time_constants: tuple[float, float | None],
) -> None:
    """The delays of a force step of ``step_force`` [N] at the end effector at ``posture``, set on ``proposal``
    (``time_constants``: the observer's and the second stage's [s], None without one)."""
    proposal.step_force = float(step_force)
    proposal.force_posture = [float(v) for v in posture]
    proposal.force_steps = {
        "collision": force_step_delays(robot, posture, step_force, proposal.collision, *time_constants),
        "contact": force_step_delays(robot, posture, step_force, proposal.contact, *time_constants),
    }
