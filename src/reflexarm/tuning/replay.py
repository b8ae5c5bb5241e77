"""Replay the product's observer offline on a recorded log: the residual the controller would have seen.

No second observer is written here: every sample of the log goes through the controller's compiled tick
(eqs. (4)-(6), the same input contract) in one call, :func:`reflexarm.control.replay`, which equals
:meth:`reflexarm.control.Controller.step` sample by sample, with the user's model and observer settings.
The residual depends on the measurements only (q, dq, tau_m, the wrist wrench with EFC, the model's
gravity), not on the commanded torque, so the reference handed to the controller is a hold at the measured
position and kappa_eps (which changes only the command) does not change it.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError, DataError
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel
from reflexarm.tuning.defaults import GAP_TIME_CONSTANTS

__all__ = [
    "RECORDED_RESIDUAL",
    "ObserverSettings",
    "ResidualReplay",
    "ThresholdWarning",
    "detector_words",
    "is_trace_file",
    "load_free_motion_log",
    "recorded_residual",
    "replay_residual",
]

#: damping_update_period of a replay's controller: larger than any log (the residual does not depend on D).
_NO_DAMPING_UPDATE = 2**31 - 1

#: Suffix of a source's name when its residual was recorded online (:func:`recorded_residual`), not replayed.
RECORDED_RESIDUAL = "(recorded residual)"


class ThresholdWarning(UserWarning):
    """Something the user should know about a threshold study (extrapolation, faults in the replay, a
    trace whose velocities are not the measured ones)."""


def detector_words(band: float | None, filter_gain: float | None) -> str:
    """", its friction model in a ... rad/s band, its residual through a second stage of K_f = ... 1/s" for what a
    detection observer runs beyond the paper's first order (its friction band, its residual's second stage); ""
    for neither."""
    text = "" if band is None else f", its friction model in a {band:g} rad/s band"
    return text + ("" if filter_gain is None else f", its residual through a second stage of K_f = {filter_gain:g} 1/s")


def check_filter_gain(value: object) -> float | None:
    """``value`` as the K_f [1/s] of the detection residual's second stage: None (no stage) or a finite number > 0.

    Raises:
        ConfigError: anything else, naming ``detection_filter_gain``.
    """
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"detection_filter_gain must be a finite gain > 0 [1/s] (or None: no stage); got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ObserverSettings:
    """The observer settings the user runs (:class:`~reflexarm.control.Controller` arguments).

    Attributes:
        observer_gain: k_o [1/s] (paper: 5 for detection).
        detection_observer_gain: k_o of a separate detection observer [1/s], or None (the detector uses
            the first observer).
        kappa_f: friction compensation in the observer (6) (0/1): with 0 a sliding joint's residual
            carries its friction.
        kappa_ext: wrist-wrench term in the observer (6), "EFC" (0/1); needs a wrench in the log.
        kappa_eps: disturbance compensation (0/1); recorded for the summary, it changes the command only,
            not the residual.
        observer_discretization: "euler" (explicit Euler of (4), k_o dt < 1) or "exact" (the first-order
            filter's zero-order-hold form, stable at any gain), as ``Controller(observer_discretization=)``.
        detection_friction_band: the detection observer subtracts the friction model in this velocity band
            [rad/s] (``Controller(detection_kappa_f=1)``); None: it follows kappa_f (the paper's).
        detection_filter_gain: K_f [1/s] of a second stage on the detection residual,
            r2_k = b r2_(k-1) + (1 - b) r_k with b = e^(-K_f dt) whatever the observer's form, r2 = 0 at the
            first tick (``Controller(detection_filter_gain=)``): the detector then compares |r2_j| with zeta_j,
            a second-order filter of the external torque with real poles -k_o and -K_f (Haddadin et al., T-RO
            2017); None: no stage, the detector sees the observer's residual r.

    Raises:
        ConfigError: a ``detection_filter_gain`` that is not a finite number > 0.
    """

    observer_gain: float = 5.0
    detection_observer_gain: float | None = None
    kappa_f: int = 0
    kappa_ext: int = 0
    kappa_eps: int = 0
    observer_discretization: str = "euler"
    detection_friction_band: float | None = None
    detection_filter_gain: float | None = None

    def __post_init__(self) -> None:
        check_filter_gain(self.detection_filter_gain)

    @property
    def detection_gain(self) -> float:
        """k_o of the residual the detector looks at [1/s]."""
        return float(self.observer_gain if self.detection_observer_gain is None else self.detection_observer_gain)

    def time_constant(self, dt: float) -> float:
        """Time constant of the detection observer's step response at the period ``dt`` [s] (the first stage;
        the second one's is :attr:`filter_time_constant`): 1/k_o for the exact form; -dt / ln(1 - k_o dt) for
        Euler (1/k_o to 0.3 % for k_o dt <= 0.005)."""
        k_o = self.detection_gain
        if self.observer_discretization == "exact":
            return 1.0 / k_o
        if k_o * dt >= 1.0:
            raise ConfigError(f"the Euler observer is unstable at k_o dt = {k_o * dt:g} >= 1; use the exact form")
        return -dt / math.log1p(-k_o * dt)

    @property
    def filter_time_constant(self) -> float | None:
        """Time constant 1/K_f of the detection residual's second stage [s] (its zero-order-hold form is exact at
        any period); None without the stage."""
        return None if self.detection_filter_gain is None else 1.0 / self.detection_filter_gain

    @property
    def detection_time_scale(self) -> float:
        """The detector's time scale [s]: the sum of its time constants, 1/k_o + 1/K_f (1/k_o without the stage).

        A slow ramp of external torque is trailed by this much (the ramp lag's asymptote; the cascade's
        k_eff = 1 / (1/k_o + 1/K_f)), and the declustering gaps count in it."""
        return 1.0 / self.detection_gain + (self.filter_time_constant or 0.0)

    @property
    def declustering_gap(self) -> float:
        """Excursions of the residual closer than this [s] are one alarm (tail fit, held-out count, ``detect``):
        :data:`~reflexarm.tuning.defaults.GAP_TIME_CONSTANTS` x :attr:`detection_time_scale`."""
        return GAP_TIME_CONSTANTS * self.detection_time_scale

    def as_dict(self) -> dict[str, object]:
        """JSON-ready settings."""
        return asdict(self)


@dataclass(frozen=True)
class ResidualReplay:
    """The detection residual of one log replayed through the controller.

    Attributes:
        source: the log's name.
        t: time (N,) [s]; residual: tau_eps_hat (N, n) [Nm] (the detector's residual); dt: the log's
            median period [s] (the controller's nominal period); fault_ticks: ticks the controller
            rejected (their residual is the previous one, as on the robot); faults: the first fault texts.
        detection_gain: k_o of the residual [1/s] and discretization ("euler"/"exact") of its observer, when
            known (a replay knows them; a recorded residual does not): :func:`~reflexarm.tuning.refilter`
            needs them to give the residual of another gain.
        detection_filter_gain: K_f [1/s] of the second stage the residual went through
            (:attr:`ObserverSettings.detection_filter_gain`), when known; None: none (or unknown, for a
            recorded residual).
    """

    source: str
    t: np.ndarray
    residual: np.ndarray
    dt: float
    fault_ticks: int
    faults: tuple[str, ...]
    detection_gain: float | None = None
    discretization: str | None = None
    detection_filter_gain: float | None = None

    @property
    def duration(self) -> float:
        """Span of the log [s] (N samples of dt)."""
        return float(self.t.size * self.dt)


def replay_residual(log: RobotLog, robot: RobotModel, settings: ObserverSettings | None = None) -> ResidualReplay:
    """Run ``log`` through a :class:`~reflexarm.control.Controller` on ``robot`` and keep its residual.

    Args:
        log: a free-motion log (q, dq, tau_m; a wrench if ``settings.kappa_ext``), the robot's joint order.
        robot: the controller's model (the user's identified model, else the robot file's nominal one).
        settings: the observer settings (default: :class:`ObserverSettings`' defaults, the paper's); with a
            ``detection_filter_gain`` the residual kept is the second stage's (the detector's), r2.

    Raises:
        ConfigError: the log has another joint count than ``robot``; EFC asked without a wrench in the log;
            the log's period makes the discrete observer unstable (k_o dt >= 1/2).
    """
    s = settings or ObserverSettings()
    if log.n != robot.n:
        raise ConfigError(f"{log.source} has {log.n} joints; the robot {robot.name!r} has {robot.n}")
    if s.kappa_ext and log.wrench is None:
        raise ConfigError(f"kappa_ext = 1 (EFC) needs the wrist wrench; {log.source} has no fx..mz columns")
    dt = float(np.median(np.diff(log.t)))
    # the keyword only with a stage: a core without the second stage still replays the first-order residual
    kf = s.detection_filter_gain
    stage: dict[str, Any] = {} if kf is None else {"detection_filter_gain": kf}
    from reflexarm.control.law_stability import UnstableLawWarning

    with warnings.catch_warnings():  # a replay never applies the law's torque (its stability at dt is moot)
        warnings.simplefilter("ignore", UnstableLawWarning)
        ctrl = _replay_controller(robot, s, stage, dt)
    # the whole log in one call of the C++ core: Controller.step on every sample, bit for bit
    from reflexarm.control import replay

    rep = replay(ctrl, log.t, log.q, log.dq, log.measured_torque, log.wrench, gravity=robot.gravity)
    t, out, n_fault, N = rep.t, rep.residual, rep.fault_ticks, rep.t.size
    faults = [f"t = {tk:.4f} s: {text}" for tk, text in rep.faults[:5]]
    if n_fault:
        warnings.warn(
            f"{log.source}: the controller rejected {n_fault} of {N} samples (their residual holds the last "
            f"value); first: {faults[0]}",
            ThresholdWarning,
            stacklevel=2,
        )
    return ResidualReplay(
        log.source, t, out, dt, n_fault, tuple(faults), s.detection_gain, s.observer_discretization,
        s.detection_filter_gain,
    )  # fmt: skip


#: Columns of a reflexarm trace (:class:`~reflexarm.sim.Trace` Parquet layout) a replay reads.
_TRACE_FIELDS = ("q_meas", "dq", "tau_m", "wrench")


def load_free_motion_log(path: str | os.PathLike[str], robot: RobotModel) -> RobotLog:
    """A free-motion log from a file: a robot log in the schema of :mod:`reflexarm.logs.files`
    (``.csv``, ``.parquet``, ``.npz``), or a reflexarm trace (``.parquet`` written by a closed-loop run).

    A trace holds the measured positions (``q_meas``) and torques but the plant's *true* velocities: the
    replayed residual then lacks the velocity noise (``k_o M_hat(q) dq`` enters the residual (4)
    unfiltered), so its thresholds come out low; a :class:`ThresholdWarning` says so. Logs written by
    :func:`reflexarm.tuning.record_free_motion_log` hold exactly what the controller measured.
    """
    from reflexarm.logs import load_log

    p = Path(path)
    if is_trace_file(p):
        return _trace_log(p, robot)
    return load_log(p, n_joints=robot.n)


def is_trace_file(path: str | os.PathLike[str]) -> bool:
    """True for a ``.parquet`` file written by :class:`~reflexarm.sim.Trace` (a closed-loop run's trace)."""
    import pyarrow.parquet as pq

    p = Path(path)
    if p.suffix.lower() != ".parquet" or not p.is_file():
        return False
    try:
        md = pq.read_schema(p).metadata or {}
    except Exception as e:  # pyarrow raises several types for a broken file
        raise DataError(f"cannot read {str(p)!r} as Parquet: {e}") from e
    return b"reflexarm.layout" in md


def _check_every_tick(p: Path) -> None:
    """DataError for a decimated trace (written with ``trace_every`` > 1): tuning needs every tick."""
    import json

    import pyarrow.parquet as pq

    md = pq.read_schema(p).metadata or {}
    try:
        every = int(json.loads(md.get(b"reflexarm.meta", b"{}")).get("trace_every", 1))
    except (ValueError, TypeError, AttributeError):
        every = 1
    if every > 1:
        raise DataError(
            f"{p.name} is a decimated trace (every {every}th tick, --trace-every): the residual's tail needs every "
            "tick; write the run's trace with --trace-every 1",
            source=p.name,
            value=every,
            expected=1,
        )


def _trace_log(p: Path, robot: RobotModel) -> RobotLog:
    import pyarrow.parquet as pq

    _check_every_tick(p)
    n = robot.n
    cols = ["t"] + [f"{f}_{j}" for f in _TRACE_FIELDS[:3] for j in range(n)] + [f"wrench_{j}" for j in range(6)]
    try:
        table = pq.read_table(p, columns=cols)
    except Exception as e:
        raise DataError(f"{p.name}: not a trace of a {n}-joint robot (columns {cols[1]}..): {e}") from e
    c = {name: table.column(name).to_numpy() for name in cols}

    def block(field: str, width: int) -> np.ndarray:
        return np.column_stack([c[f"{field}_{j}"] for j in range(width)])

    warnings.warn(
        f"{p.name} is a reflexarm trace: it holds the plant's true joint velocities, not the measured ones, so "
        "the replayed residual lacks the velocity noise and the thresholds come out low; record free motion "
        "with reflexarm.tuning.record_free_motion_log (or log the measured dq) for thresholds to use",
        ThresholdWarning,
        stacklevel=3,
    )
    return RobotLog(
        t=c["t"],
        q=block("q_meas", n),
        dq=block("dq", n),
        tau=block("tau_m", n),
        wrench=block("wrench", 6),
        source=p.name,
        notes=("read from a reflexarm trace (true velocities)",),
    )


def recorded_residual(path: str | os.PathLike[str], n: int) -> ResidualReplay:
    """The residual a closed-loop run's controller computed online, read from its trace (``.parquet``).

    It saw the measured signals (with their noise), so it is the right residual to tune on when the run's
    controller is the one the thresholds are for (its model, k_o, kappa_f, EFC): e.g. ``reflexarm simulate
    free-motion``, whose trace holds the plant's true velocities, which a replay would lack the noise of.

    Raises:
        DataError: not a reflexarm trace, or not of an ``n``-joint arm.
    """
    import pyarrow.parquet as pq

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{str(p)!r}: no such file (a recorded residual is read from a reflexarm trace, .parquet)")
    if not is_trace_file(p):
        raise DataError(
            f"{p.name}: a recorded residual is read from a reflexarm trace (.parquet); this file is not one"
        )
    _check_every_tick(p)
    cols = ["t"] + [f"residual_{j}" for j in range(n)]
    try:
        table = pq.read_table(p, columns=cols)
    except Exception as e:
        raise DataError(f"{p.name}: not a trace of a {n}-joint robot (columns {cols[1]}..): {e}") from e
    t = table.column("t").to_numpy()
    r = np.column_stack([table.column(c).to_numpy() for c in cols[1:]])
    if t.size < 2:
        raise DataError(f"{p.name}: a trace needs at least 2 samples; got {t.size}")
    return ResidualReplay(f"{p.name} {RECORDED_RESIDUAL}", t, r, float(np.median(np.diff(t))), 0, ())


def _replay_controller(robot: RobotModel, s: ObserverSettings, stage: dict[str, Any], dt: float) -> Any:
    """The controller a replay steps (no detection, no reaction, no torque limit)."""
    from reflexarm.control import Controller, detection_friction

    return Controller(
        robot,
        observer_gain=s.observer_gain,
        detection_observer_gain=s.detection_observer_gain,
        threshold=None,
        reaction="none",
        kappa_f=s.kappa_f,
        kappa_ext=s.kappa_ext,
        kappa_eps=s.kappa_eps,
        observer_discretization=s.observer_discretization,
        **detection_friction(s.detection_friction_band),
        **stage,
        dt=dt,
        torque_limit=None,
        # the damping matrix shapes the command only, never the residual: computed once instead of every 10
        # samples (~17 % of a replayed sample)
        damping_update_period=_NO_DAMPING_UPDATE,
    )
