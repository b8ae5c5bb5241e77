"""Disturbance compensation (DC) and end-effector force compliance (EFC): the simulation of Sec. III-C.

Everything runs on the built-in Atlas v5 left arm (or the arm ``CompensationSetup.robot`` names, loaded
with ``robot_options``; it holds its start posture, :func:`~reflexarm.experiments.any_arm.start_posture`)
in MuJoCo (the *true* arm) with the controller's model
perturbed by :mod:`reflexarm.robots.perturbation` (or an identified model, ``model_file``) and the
sensors carrying the paper's noise. This module holds the setup and the single run; Fig. 12 is
:mod:`reflexarm.experiments.efc_step`, Fig. 11 is :mod:`reflexarm.experiments.compliance_loss`, Fig. 3
:mod:`reflexarm.experiments.mode_table`, Figs. 13-14 :mod:`reflexarm.experiments.robustness`.

The Fig. 12 setup (:class:`CompensationSetup`): the arm holds its home posture with controller (2),
k_i = 150 Nm/rad, d_xi = 0.3, k_o = 10 1/s, observer cut-off 30 Nm, kappa_f = 1, +-10 % model errors and
the paper's sensor noise; a 50 N force step acts on the end effector from 0.5 s to 3.5 s, the run lasts
5 s.

*Normal to the end effector* is the direction of :class:`reflexarm.sim.EndEffectorForce`'s default:
along the tool axis, from the end-effector point towards the wrist force/torque sensor (on Atlas the
hand's y axis), i.e. a push against the tip of the tool, resolved at the switch-on time and then held
constant in the world.

**kappa_f = 1 in the simulation** (the default here). The paper disables friction compensation on the
real arm ("this feature is disabled in the experiments with kappa_f = 0", Sec. III-A/B), but its
simulation of Sec. III-C-2 perturbs "the friction coefficients" among the model errors: those factors
act on nothing unless the controller uses tau_f_hat, so the simulated controller (2) had kappa_f = 1.
With kappa_f = 0 the whole plant friction becomes part of delta: the DC runs compensate it while the
compliant reference keeps it, a level-independent floor that hid the model errors in Fig. 13 (issue 7).
The experiments that stand for the real arm (:func:`~reflexarm.experiments.compliance_loss.compliance_loss`,
:func:`~reflexarm.experiments.mode_table.mode_table`) use kappa_f = 0, as the paper's experiments did.

The true arm's friction (``plant_friction``):

* ``"smooth"`` (default of :class:`CompensationSetup`, i.e. of the simulations of Figs. 12-14): the
  Table I coefficients as a continuous-time law ``mu_C sgn_band(dq) + d_v dq`` without stiction (the
  controller library's smooth sign, band 0.02 rad/s): the "continuous time forward dynamics derived from
  (1) ... with viscous and Coulomb friction and parameters from Table I" of the paper's simulation;
* ``"dry"`` (default of the real-arm experiments, Figs. 3 and 11): Table I friction as MuJoCo
  ``frictionloss``/``damping``: true dry friction with stiction; a joint whose load stays below mu_C does
  not move;
* ``"none"``: a frictionless arm (diagnostic).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.control import Controller
from reflexarm.control.law_stability import experiment_stiffness
from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import start_posture
from reflexarm.experiments.metrics import msie
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot, perturb_model
from reflexarm.signals import Reference
from reflexarm.sim import PAPER_NOISE, EndEffectorForce, Plant, Scene, SensorNoise, Trace
from reflexarm.sim.compiled_loop import run_fast

__all__ = [
    "CASES",
    "NOISE_CHANNELS",
    "NO_CUTOFF",
    "PLANT_FRICTION",
    "CompensationSetup",
    "HoldReference",
    "build_plant",
    "controller_model",
    "ee_positions",
    "held_posture",
    "make_controller",
    "msie_against",
    "robot_options",
    "reference_run",
    "run_case",
    "true_robot",
    "write_json",
]

PLANT_FRICTION = ("dry", "smooth", "none")
#: Sensor channels of :class:`reflexarm.sim.SensorNoise` (``noise_channels`` picks some of them).
NOISE_CHANNELS = ("q", "dq", "gravity", "tau_m", "force", "torque")

#: Observer cut-off used to show the effect of the 30 Nm one: far above any torque of these runs [Nm].
NO_CUTOFF = 1e9

#: The three runs of Fig. 12: (kappa_eps, kappa_ext).
CASES: dict[str, tuple[int, int]] = {"no DC": (0, 0), "DC": (1, 0), "DC+EFC": (1, 1)}


@dataclass(frozen=True)
class CompensationSetup:
    """The simulation of Fig. 12 (defaults: the paper's values; see the module docstring).

    Attributes:
        robot: built-in robot name or robot file.
        robot_options: keyword arguments of :func:`~reflexarm.robots.load_robot` as (name, value) pairs
            (``ee_frame``, ``sensor_frame``, ``base``, ``tip``, ``locked``; a dict value as pairs too).
        stiffness: k_i [Nm/rad].
        damping_ratio: d_xi [-].
        observer_gain: k_o [1/s].
        residual_limit: cut-off of the compensated observer output [Nm].
        kappa_f: friction compensation in (2) and (6) (0/1); 1 in the paper's simulation (module docstring).
        force: end-effector force step [N].
        t_on, t_off: force step on and off [s].
        duration: T_f, run length [s] (the MSIE (20) integrates over it).
        model_error: p of the model errors, a fraction (0.1 = +-10 %).
        noise_scale: s, factor on the paper's sensor noise levels.
        plant_friction: the true arm's friction, one of :data:`PLANT_FRICTION`.
        posture: held joint posture [rad]; None: the robot's home.
        model_file: an identified-model file (``identify dynamics``) used as the controller's model
            instead of the perturbed true model; None: the perturbed model.
        noise_channels: the sensor channels that carry noise (subset of :data:`NOISE_CHANNELS`); None:
            all (the paper). A diagnostic: which channel drives an effect of the noise (Fig. 14).
    """

    robot: str = "atlas_v5_left_arm"
    robot_options: tuple[tuple[str, Any], ...] = ()
    stiffness: float = 150.0
    damping_ratio: float = 0.3
    observer_gain: float = 10.0
    residual_limit: float = 30.0
    kappa_f: int = 1
    force: float = 50.0
    t_on: float = 0.5
    t_off: float = 3.5
    duration: float = 5.0
    model_error: float = 0.1
    noise_scale: float = 1.0
    plant_friction: str = "smooth"
    posture: tuple[float, ...] | None = None
    model_file: str | None = None
    noise_channels: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.kappa_f not in (0, 1) or isinstance(self.kappa_f, bool):
            raise ConfigError(f"kappa_f must be 0 or 1; got {self.kappa_f!r}")
        if self.noise_channels is not None:
            bad = [c for c in self.noise_channels if c not in NOISE_CHANNELS]
            if bad or not self.noise_channels:
                raise ConfigError(
                    f"unknown noise channel(s) {bad or list(self.noise_channels)!r}; choose from: "
                    f"{', '.join(NOISE_CHANNELS)}"
                )
        if self.plant_friction not in PLANT_FRICTION:
            raise ConfigError(
                f"unknown plant friction {self.plant_friction!r}; choose one of: {', '.join(PLANT_FRICTION)}"
            )
        for name in ("stiffness", "observer_gain", "residual_limit", "duration"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ConfigError(f"{name} must be positive; got {v!r}")
        for name in ("model_error", "noise_scale", "force", "damping_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be non-negative; got {v!r}")
        if not 0 <= self.t_on < self.t_off:
            raise ConfigError(f"need 0 <= t_on < t_off; got t_on={self.t_on!r}, t_off={self.t_off!r}")

    def as_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (JSON-serialisable)."""
        return asdict(self)

    def sensor_noise(self, scale: float | None = None) -> SensorNoise:
        """The paper's noise levels times ``scale`` (default: the setup's), on :attr:`noise_channels` only."""
        levels = PAPER_NOISE.scaled(self.noise_scale if scale is None else scale).as_dict()
        if self.noise_channels is not None:
            levels = {k: (v if k in self.noise_channels else 0.0) for k, v in levels.items()}
        return SensorNoise(**levels)

    @property
    def load_window(self) -> tuple[float, float]:
        """Steady state under the load: the last 0.5 s before the release [s]."""
        return (max(self.t_on, self.t_off - 0.5), self.t_off)

    @property
    def pre_window(self) -> tuple[float, float]:
        """Steady state before the load: the last 0.2 s before the step [s]."""
        return (max(0.0, self.t_on - 0.2), self.t_on)


class HoldReference:
    """A constant joint reference (quasi-static: the paper's "quasi-static movement")."""

    #: the same Reference at every t: the compiled loop takes it once for the whole run
    is_constant = True

    def __init__(self, q: np.ndarray) -> None:
        self.reference = Reference.hold(np.asarray(q, dtype=float))

    def sample(self, t: float) -> Reference:
        """The held reference (the same at every t)."""
        return self.reference

    def describe(self) -> dict[str, object]:
        """JSON-serialisable description for ``Trace.meta``."""
        return {"type": "hold", "q": self.reference.q_d.tolist()}


_ROBOTS: dict[str, RobotModel] = {}


def robot_options(options: dict[str, Any] | None) -> tuple[tuple[str, Any], ...]:
    """``load_robot`` keyword arguments as the hashable pairs of :attr:`CompensationSetup.robot_options`."""
    out = []
    for key, value in sorted((options or {}).items()):
        if value is None:
            continue
        out.append((key, tuple(sorted(value.items())) if isinstance(value, dict) else value))
    return tuple(out)


def _load_kwargs(options: Sequence[Sequence[Any]]) -> dict[str, Any]:
    kwargs: dict[str, Any] = {}
    for key, value in options:
        kwargs[str(key)] = {str(k): float(v) for k, v in value} if key == "locked" else value
    return kwargs


def true_robot(robot: str | CompensationSetup, options: Sequence[Sequence[Any]] = ()) -> RobotModel:
    """The true robot model of a setup (or of a robot name/file with ``load_robot`` ``options`` pairs),
    loaded once per process; callers get copies where they modify."""
    name = robot if isinstance(robot, str) else robot.robot
    if isinstance(robot, CompensationSetup):
        options = robot.robot_options
    key = f"{name}|{tuple(tuple(o) for o in options)!r}"
    if key not in _ROBOTS:
        _ROBOTS[key] = load_robot(name, **_load_kwargs(options))
    return _ROBOTS[key]


def held_posture(setup: CompensationSetup, robot: RobotModel) -> np.ndarray:
    """The setup's held joint posture [rad] (the robot's start posture unless ``setup.posture``: its home
    on the built-in robots, see :func:`~reflexarm.experiments.any_arm.start_posture`)."""
    q = start_posture(robot) if setup.posture is None else np.asarray(setup.posture, dtype=float)
    if q.shape != (robot.n,):
        raise ConfigError(f"posture must have {robot.n} joint values; got {q.shape}")
    return q.copy()


def build_plant(
    setup: CompensationSetup, scenes: Sequence[Scene], *, noise_scale: float, seed: int
) -> tuple[Plant, RobotModel]:
    """The true arm with the setup's friction variant and scaled paper noise (reset at the posture)."""
    robot = true_robot(setup)
    true_friction = None
    if setup.plant_friction != "dry":
        true_friction = CoulombViscousFriction.zeros(robot.n)
    # the smooth law is evaluated by MuJoCo (actuators with a velocity bias), not by a Python callback
    smooth = robot.friction if setup.plant_friction == "smooth" else None
    plant = Plant(
        robot,
        scene=list(scenes),
        noise=setup.sensor_noise(noise_scale),
        seed=seed,
        true_friction=true_friction,
        smooth_friction=smooth,
    )
    plant.reset(held_posture(setup, robot))
    return plant, robot


def controller_model(setup: CompensationSetup, model_error: float | None = None, model_seed: int = 0) -> RobotModel:
    """The controller's model: the identified ``setup.model_file``, or the true model perturbed by ``model_error``.

    Raises:
        ConfigError: ``model_file`` together with a non-zero explicit ``model_error`` (an identified model
            is used as it is).
    """
    robot = true_robot(setup)
    if setup.model_file is not None:
        if model_error:
            raise ConfigError(
                f"the setup uses the identified model {setup.model_file!r}; got model_error {model_error!r} as well"
            )
        from reflexarm.ident import load_identified_model

        return load_identified_model(setup.model_file, robot)
    level = setup.model_error if model_error is None else model_error
    return perturb_model(robot, level, model_seed) if level > 0 else robot


def make_controller(
    setup: CompensationSetup,
    kappa_eps: int,
    kappa_ext: int,
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    residual_limit: float | None = None,
    threshold: float | None = None,
    reaction: str = "none",
) -> Controller:
    """The controller (2) of the setup on :func:`controller_model` (default level: the setup's)."""
    model = controller_model(setup, model_error, model_seed)
    return Controller(
        model,
        stiffness=experiment_stiffness(model, setup.stiffness, setup.damping_ratio),
        damping_ratio=setup.damping_ratio,
        observer_gain=setup.observer_gain,
        threshold=threshold,
        reaction=reaction,
        kappa_f=setup.kappa_f,
        kappa_eps=kappa_eps,
        kappa_ext=kappa_ext,
        residual_limit=setup.residual_limit if residual_limit is None else residual_limit,
    )


def run_case(
    setup: CompensationSetup,
    kappa_eps: int,
    kappa_ext: int,
    *,
    model_error: float | None = None,
    noise_scale: float | None = None,
    model_seed: int = 0,
    noise_seed: int = 0,
    residual_limit: float | None = None,
    scenes: Sequence[Scene] | None = None,
    progress: bool = False,
) -> Trace:
    """One run of the Fig. 12 experiment (or, with ``scenes``, of another load on the same setup).

    Args:
        setup: the experiment.
        kappa_eps, kappa_ext: the controller setting (see :data:`CASES`).
        model_error: p of this run (default: the setup's); 0 runs the exact model.
        noise_scale: s of this run (default: the setup's); 0 runs without noise.
        model_seed, noise_seed: seeds of the model-error draw and of the sensor noise.
        residual_limit: override of the observer cut-off [Nm] (e.g. :data:`NO_CUTOFF` to show its effect).
        scenes: the loads (default: the 50 N end-effector step of the setup).
    """
    if scenes is None:
        scenes = [EndEffectorForce(setup.force, t_on=setup.t_on, t_off=setup.t_off)]
    noise = setup.noise_scale if noise_scale is None else noise_scale
    plant, robot = build_plant(setup, scenes, noise_scale=noise, seed=noise_seed)
    ctrl = make_controller(
        setup, kappa_eps, kappa_ext, model_error=model_error, model_seed=model_seed, residual_limit=residual_limit
    )
    # the compiled loop (one C++ call) when the run allows it, else the Python loop: the same trace
    trace = run_fast(plant, ctrl, HoldReference(held_posture(setup, robot)), setup.duration, progress=progress)
    trace.meta.update(
        {
            "experiment": "compensation",
            "setup": setup.as_dict(),
            "kappa_eps": kappa_eps,
            "kappa_ext": kappa_ext,
            "model_error": setup.model_error if model_error is None else model_error,
            "noise_scale": noise,
            "model_seed": model_seed,
            "model_file": setup.model_file,
            "noise_seed": noise_seed,
            "residual_limit": setup.residual_limit if residual_limit is None else residual_limit,
        }
    )
    return trace


def reference_run(setup: CompensationSetup) -> Trace:
    """q_ref of (20): "the compliant behavior of the controller without disturbance compensation and
    without model errors or measurement noise": controller (2) of the setup (same gains, same kappa_f)
    with kappa_eps = 0 on the exact model, no sensor noise, the same load."""
    exact = replace(setup, model_file=None, model_error=0.0, noise_scale=0.0)
    return run_case(exact, 0, 0, model_error=0.0, noise_scale=0.0)


def ee_positions(trace: Trace, robot: RobotModel | None = None, frame: str | None = None) -> np.ndarray:
    """World positions (N, 3) [m] of the end effector (or ``frame``) along the trace's true joint positions."""
    if robot is None:
        meta = trace.meta.get("setup", {})
        robot = true_robot(str(meta.get("robot", "atlas_v5_left_arm")), meta.get("robot_options", ()))
    return np.array([robot.compute_frame_pose(q, frame)[1] for q in trace.q])


def write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON (numpy scalars converted)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(obj, indent=2, default=lambda x: x.item() if isinstance(x, np.generic) else str(x)))
    return p


def msie_against(trace: Trace, reference: Trace) -> float:
    """MSIE (20) of a run against a reference run on the same time grid."""
    return msie(trace.t, trace.q, reference.q)
