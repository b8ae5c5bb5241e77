"""Power and force limiting (ISO/TS 15066): an arm swinging its end effector into a human body region, simulated
with the arm's own controller, collision detection and reaction, beside the standard's analytic prediction.

One run (:func:`run_region_contact`): the demo swing retimed to a peak end-effector speed
(:func:`~reflexarm.experiments.pfl_placement.swing_at_speed`), the region placed across the path where the
speed peaks (:func:`~reflexarm.experiments.pfl_placement.place_region`), the plant's
:class:`~reflexarm.sim.human_contact.HumanContact` (transient: the region's mass recoils; clamped: a wall
behind it), the controller of :data:`PFL_SETTING` with the chosen reaction (``None`` threshold: detection
off). Measured from the plant: the first peak of the contact force (the transient), the largest force, the
detection delay after first contact and, clamped, when the force falls below F_QS for good.

The analytic prediction at the measured approach: F = v sqrt(mu k) with mu from the arm's posture-dependent
m_R(q, u) at the last tick before contact (and from the standard's M/2 + m_L beside it). The standard's model
is a free mass; the controlled arm is driven on during the impact (the impedance sees the arm fall behind its
reference): ``controller_force_at_peak_N`` is that drive force at the point along u at the peak, measured from
the commanded torques, and ``controller_corrected_force_N`` the prediction plus the share of it a linearly
rising force adds at the peak (:data:`RAMP_SHARE`): a decomposition of the difference, not an independent
prediction.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.experiments.collision import CollisionSetting, controller_model
from reflexarm.experiments.pfl_motion import SampledMotion, SpeedLimitError
from reflexarm.experiments.pfl_placement import place_region, place_region_on_motion, swing_at_speed
from reflexarm.robots import CoulombViscousFriction, RobotModel
from reflexarm.safety import (
    ContactPoint,
    body_region,
    effective_mass,
    permissible_speed_for_mass,
    point_jacobian,
    standard_robot_mass,
)
from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise, Trace, run_fast
from reflexarm.sim.human_contact import CONTACT_MODES, HumanContact
from reflexarm.sim.runner import TrajectoryLike

__all__ = [
    "PFL_REACTIONS",
    "PFL_SETTING",
    "QS_WINDOW_S",
    "ContactResult",
    "contact_result",
    "run_motion_contact",
    "run_region_contact",
]

#: The controller of the study: the demo's "Compliant" joint stiffness (100 Nm/rad; the "Stiff" 300 Nm/rad
#: pushes harder during an impact, see the README), the demo's detection (k_o = 5 1/s, zeta = 11 Nm).
PFL_SETTING = CollisionSetting("PFL", stiffness=100.0, observer_gain=5.0, threshold=11.0, reaction="gravity")
#: The reactions of the collision pipeline the study runs (besides detection off).
PFL_REACTIONS = ("none", "gravity", "brake", "retract", "compliant")
#: The share of the controller's drive force F_c that adds to the peak when F_c rises linearly from 0 at first
#: contact to F_c at the peak (a quarter period pi/(2 omega) later) on the undamped two-mass spring: the forced
#: response k x(t) = F_c (1 - sin(omega t) / (omega t)) at omega t = pi/2 is F_c (1 - 2/pi) [-].
RAMP_SHARE = 1.0 - 2.0 / math.pi
#: The clamped force must be below F_QS this long after detection [s] (the issue's target).
QS_WINDOW_S = 0.5
#: How long a run goes on after the reference reaches the region [s]: transient, clamped.
RUN_AFTER_CONTACT_S = {"transient": 0.4, "clamped": 1.2}


@dataclass(frozen=True)
class ContactResult:
    """One run's numbers (units in the names; None where the run has no such event)."""

    arm: str
    region: str
    mode: str
    reaction: str
    detection: bool
    reference_speed_m_s: float
    approach_speed_m_s: float | None
    effective_mass_kg: float | None
    standard_mass_kg: float
    peak_force_N: float | None
    max_force_N: float
    analytic_force_N: float | None
    analytic_standard_force_N: float | None
    permissible_speed_m_s: float | None
    standard_permissible_speed_m_s: float
    controller_force_at_peak_N: float | None
    controller_corrected_force_N: float | None
    contact_time_s: float | None
    detection_delay_s: float | None
    detected_before_contact: bool
    below_qs_after_detection_s: float | None
    max_force_after_window_N: float | None
    F_T_N: float
    F_QS_N: float
    contact_point: str = "ee"
    motion: str = "swing"
    time_scale: float | None = None

    @property
    def simulated_over_analytic(self) -> float | None:
        if self.peak_force_N is None or not self.analytic_force_N:
            return None
        return self.peak_force_N / self.analytic_force_N

    def row(self) -> dict[str, Any]:
        out = asdict(self)
        out["simulated_over_analytic"] = self.simulated_over_analytic
        return out


def _first_peak(F: np.ndarray, on: int) -> int:
    """Index of the first local maximum of F from ``on`` (the transient's peak)."""
    for i in range(on, F.size - 1):
        if F[i + 1] < F[i]:
            return i
    return F.size - 1


def _controller_force(
    robot: RobotModel, trace: Trace, before: int, peak: int, u: np.ndarray, m_r: float, point: ContactPoint
) -> float:
    """The drive force the controller adds along u at the point between the last tick before contact and the
    peak: m_R u^T J M^-1 (tau[peak] - tau[before]) [N] (positive: into the body)."""
    q = trace.q[peak]
    J, _ = point_jacobian(robot, q, point.link, point.point)
    dtau = trace.tau[peak] - trace.tau[before]
    return float(m_r * (u @ J @ np.linalg.solve(robot.compute_mass_matrix(q), dtau)))


def _below_after(t: np.ndarray, F: np.ndarray, t_det: float, limit: float) -> float | None:
    """Seconds after ``t_det`` from which F stays below ``limit`` to the end of the run (None: never)."""
    above = np.flatnonzero((F >= limit) & (t >= t_det))
    if above.size == 0:
        return 0.0
    last = int(above[-1])
    return None if last >= t.size - 1 else float(t[last + 1] - t_det)


def contact_result(
    robot: RobotModel,
    trace: Trace,
    scene: HumanContact,
    reaction: str,
    detection: bool,
    point: ContactPoint | None = None,
) -> ContactResult:
    """The measures of one run (module docstring) from its trace; ``point`` the arm's contact point (default the
    end effector)."""
    point = ContactPoint(robot.ee_frame) if point is None else point
    region = scene.region
    F = trace.extras[f"{scene.name}_force"][:, 0]
    m_std = standard_robot_mass(robot)
    m_h = region.human_mass if scene.mode == "transient" else math.inf
    common: dict[str, Any] = dict(
        arm=robot.name,
        region=region.name,
        mode=scene.mode,
        reaction=reaction,
        detection=detection,
        reference_speed_m_s=float(trace.meta.get("reference_speed_m_s", math.nan)),
        standard_mass_kg=m_std,
        max_force_N=float(F.max()),
        standard_permissible_speed_m_s=permissible_speed_for_mass(m_std, region) if m_h < math.inf else math.nan,
        detected_before_contact=False,
        F_T_N=region.transient_force,
        F_QS_N=region.quasi_static_force,
        contact_point=str(trace.meta.get("contact_point", "ee")),
        motion=str(trace.meta.get("motion", "swing")),
        time_scale=trace.meta.get("time_scale"),
    )
    t_det = trace.first_time(trace.collision) if detection else None
    hits = np.flatnonzero(F > 0.0)
    if t_det is not None and (hits.size == 0 or t_det < float(trace.t[hits[0]])):
        common["detected_before_contact"] = True  # a false alarm: the reaction started before any contact
    if hits.size == 0:
        none = dict.fromkeys(f for f in ContactResult.__dataclass_fields__ if f not in common)
        return ContactResult(**{**none, **common})  # type: ignore[arg-type]
    on = int(hits[0])
    before = max(on - 1, 0)
    u = scene.normal
    J, _ = point_jacobian(robot, trace.q[before], point.link, point.point)
    v = float(u @ J @ trace.dq[before])
    m_r = effective_mass(robot, trace.q[before], point.link, point.point, u)
    k = region.spring_constant_si
    mu = 1.0 / (1.0 / m_h + 1.0 / m_r)
    mu_std = 1.0 / (1.0 / m_h + 1.0 / m_std)
    peak = _first_peak(F, on)
    f_ctrl = _controller_force(robot, trace, before, peak, u, m_r, point)
    t_on = float(trace.t[on])
    after = None
    below = None
    if t_det is not None:
        below = _below_after(trace.t, F, t_det, region.quasi_static_force)
        late = trace.t >= t_det + QS_WINDOW_S
        after = float(F[late].max()) if late.any() else None
    return ContactResult(
        **common,
        approach_speed_m_s=v,
        effective_mass_kg=m_r,
        peak_force_N=float(F[peak]),
        analytic_force_N=v * math.sqrt(mu * k),
        analytic_standard_force_N=v * math.sqrt(mu_std * k),
        permissible_speed_m_s=permissible_speed_for_mass(m_r, region) if m_h < math.inf else math.nan,
        controller_force_at_peak_N=f_ctrl,
        controller_corrected_force_N=v * math.sqrt(mu * k) + RAMP_SHARE * f_ctrl,
        contact_time_s=t_on,
        detection_delay_s=None if t_det is None else t_det - t_on,
        below_qs_after_detection_s=below,
        max_force_after_window_N=after,
    )


@dataclass(frozen=True)
class _ContactRun:
    """How one contact run is simulated (the keyword arguments :func:`run_region_contact` and
    :func:`run_motion_contact` share), checked once: the contact mode, the reaction, detection on/off, the
    controller's model (``model_error``, ``model_seed``), the sensor noise and its seed, the plant's friction
    (``"file"`` or ``"none"``) and the controller ``setting``."""

    mode: str
    reaction: str
    detection: bool
    model_error: float | None
    model_seed: int
    noise: SensorNoise
    seed: int
    plant_friction: str
    setting: CollisionSetting

    def __post_init__(self) -> None:
        if self.mode not in CONTACT_MODES:
            raise ConfigError(f"unknown contact mode {self.mode!r}; choose one of: {', '.join(CONTACT_MODES)}")
        if self.reaction not in PFL_REACTIONS:
            raise ConfigError(f"unknown reaction {self.reaction!r}; choose one of: {', '.join(PFL_REACTIONS)}")
        if self.plant_friction not in ("file", "none"):
            raise ConfigError(f"unknown plant_friction {self.plant_friction!r}; choose one of: file, none")


def _simulate(
    robot: RobotModel,
    scene: HumanContact,
    trajectory: TrajectoryLike,
    start: tuple[np.ndarray, np.ndarray | None],
    duration: float,
    run: _ContactRun,
) -> Trace:
    """Run the study's controller (``run``'s setting, reaction, detection and model) on the plant (``run``'s noise,
    seed and friction) with ``scene`` from state ``start`` (q, dq) for ``duration`` [s]."""
    friction = CoulombViscousFriction.zeros(robot.n) if run.plant_friction == "none" else None
    plant = Plant(robot, scene=scene, noise=run.noise, seed=run.seed, true_friction=friction)
    plant.reset(*start)
    ctrl_model, model_info = controller_model(robot, run.model_error, run.model_seed)
    setting = run.setting
    chosen = replace(setting, reaction=run.reaction, threshold=setting.threshold if run.detection else None)
    trace = run_fast(plant, chosen.controller(ctrl_model), trajectory, duration)
    trace.meta.update(
        {
            "experiment": "pfl",
            "robot": robot.name,
            "setting": asdict(chosen),
            "controller_model": model_info,
            "plant_friction": run.plant_friction,
        }
    )
    return trace


def run_region_contact(
    robot: RobotModel,
    region: str,
    speed: float,
    *,
    mode: str = "transient",
    reaction: str = "none",
    detection: bool = True,
    model_error: float | None = None,
    model_seed: int = 0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    plant_friction: str = "file",
    setting: CollisionSetting = PFL_SETTING,
) -> tuple[ContactResult, Trace]:
    """One contact of the demo swing at peak end-effector speed ``speed`` [m/s] with ``region`` (module docstring).

    ``detection=False`` runs without detection (threshold None; no reaction can start); ``model_error`` and
    ``model_seed`` choose the controller's model as in the collision experiments
    (:func:`~reflexarm.experiments.collision.controller_model`); ``plant_friction`` "file" or "none".

    Raises:
        ConfigError: an unknown region, mode, reaction or plant friction; a speed the swing cannot reach; a
            region the arm's path cannot take (another link would hit it first).
    """
    run = _ContactRun(
        mode=mode, reaction=reaction, detection=detection, model_error=model_error, model_seed=model_seed,
        noise=noise, seed=seed, plant_friction=plant_friction, setting=setting,
    )  # fmt: skip
    body_region(region)
    trajectory, _ = swing_at_speed(robot, speed)
    placement = place_region(robot, trajectory)
    scene = HumanContact(region, placement.surface, placement.normal, mode=mode)
    start = (trajectory.sample(0.0).q_d, None)
    trace = _simulate(robot, scene, trajectory, start, placement.contact_time + RUN_AFTER_CONTACT_S[mode], run)
    trace.meta.update({"placement": placement.describe(), "reference_speed_m_s": placement.reference_speed})
    return contact_result(robot, trace, scene, reaction, detection), trace


def run_motion_contact(
    robot: RobotModel,
    motion: SampledMotion,
    region: str,
    speed: float | None = None,
    *,
    point: str = "ee",
    mode: str = "transient",
    reaction: str = "none",
    detection: bool = True,
    model_error: float | None = None,
    model_seed: int = 0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    plant_friction: str = "file",
    setting: CollisionSetting = PFL_SETTING,
) -> tuple[ContactResult, Trace]:
    """One contact of ``region`` with the point ``point`` (``ee`` or ``link<j>``,
    :func:`~reflexarm.experiments.pfl_placement.contact_point_on`) on a sampled motion (a trajectory file, an
    excitation), the region placed where that point moves fastest
    (:func:`~reflexarm.experiments.pfl_placement.place_region_on_motion`). ``speed`` [m/s]: the motion is
    time-scaled so that the point's reference speed there is ``speed`` (None: the motion's own timing). The run
    starts shortly before the contact from the motion's state there. Other arguments as
    :func:`run_region_contact`.

    Raises:
        ConfigError: as :func:`run_region_contact`; a point the region cannot be placed for; a speed whose time
            scaling needs a joint beyond its velocity limit (the message names the joint and the largest speed
            the motion reaches within the limits).
    """
    run = _ContactRun(
        mode=mode, reaction=reaction, detection=detection, model_error=model_error, model_seed=model_seed,
        noise=noise, seed=seed, plant_friction=plant_friction, setting=setting,
    )  # fmt: skip
    body_region(region)
    base = motion.played(1.0)
    placement = place_region_on_motion(robot, base, point)
    scale = 1.0 if speed is None else _time_scale(robot, base, placement.reference_speed, speed, point)
    played = motion.played(scale, placement.start_time)
    scene = HumanContact(
        region, placement.surface, placement.normal, mode=mode, arm_body=placement.arm_body,
        arm_point=placement.point.point,
    )  # fmt: skip
    start = played.sample(0.0)
    t_contact = (placement.contact_time - placement.start_time) / scale
    trace = _simulate(robot, scene, played, (start.q_d, start.dq_d), t_contact + RUN_AFTER_CONTACT_S[mode], run)
    trace.meta.update(
        {
            "placement": placement.describe(),
            "reference_speed_m_s": placement.reference_speed * scale,
            "contact_point": point,
            "motion": motion.name,
            "time_scale": scale,
        }
    )
    return contact_result(robot, trace, scene, reaction, detection, placement.point), trace


def _time_scale(robot: RobotModel, motion: SampledMotion, v_ref: float, speed: float, point: str) -> float:
    """The time scale that brings the point's reference speed ``v_ref`` [m/s] to ``speed`` [m/s], or a ConfigError
    if a joint would exceed its velocity limit."""
    if not (math.isfinite(speed) and speed > 0.0):
        raise ConfigError(f"speed must be a positive speed [m/s]; got {speed!r}")
    scale = speed / v_ref
    ratio, j = motion.velocity_ratio(robot)
    if ratio * scale > 1.0 + 1e-9:
        raise SpeedLimitError(
            f"{robot.name}: {motion.name} time-scaled x{scale:.3g} to bring {point} to {speed:g} m/s needs joint "
            f"{j + 1} at {ratio * scale:.3g} x its velocity limit {robot.velocity_limit[j]:.3g} rad/s; within the "
            f"limits {point} reaches at most {v_ref / ratio:.3g} m/s on this motion",
            speed=speed,
            reachable_speed=v_ref / ratio,
            joint=j,
        )
    return scale
