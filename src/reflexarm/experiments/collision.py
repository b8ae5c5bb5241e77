"""Collision experiments of Sec. III-A/B: end-effector collision with a padded cinderblock (Figs. 7-8)
and a link collision at the elbow (Figs. 9-10), simulated on the built-in Atlas arm (the paper's
setting, kept exactly) or on any serial arm (``robot=``: the motions and scenes are derived from its
kinematics and limits by :mod:`reflexarm.experiments.any_arm`).

The conditions are those of a real arm by default: the sensors carry the paper's noise
(:data:`reflexarm.sim.PAPER_NOISE`) and the controller's model is *not* the plant's: it has uniform
errors within +-``DEFAULT_MODEL_ERROR`` (Sec. III-C's 10 %) on masses, inertias, COM coordinates and
friction, drawn with ``model_seed``. ``model=`` hands in another model (e.g. an identified one) and
``model_error=0`` the plant's exact one.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from reflexarm.control import Controller, detection_friction
from reflexarm.control.collision.react import ReactionSettings
from reflexarm.control.law_stability import experiment_stiffness
from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import (
    ee_swing_plan,
    is_paper_arm,
    loaded_waypoints,
    start_posture,
)
from reflexarm.experiments.block_placement import place_cinderblock
from reflexarm.experiments.collision_summary import (
    PAPER,
    compare_with_paper,
    summarize_ee_collision,
    summarize_link_collision,
    write_outputs,
)
from reflexarm.experiments.free_motion_variation import varied_cycles
from reflexarm.experiments.link_push import held_stick_tip, link_push_plan, move_start
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot, perturb_model
from reflexarm.sim import (
    PAPER_NOISE,
    Cinderblock,
    ElbowStick,
    JointTrajectory,
    Plant,
    SensorNoise,
    Trace,
)
from reflexarm.sim.compiled_loop import run_fast

__all__ = [
    "DEFAULT_MODEL_ERROR",
    "EE_BLOCKS",
    "PAPER",
    "CollisionSetting",
    "EE_SETTINGS",
    "LINK_SETTING",
    "PLANT_FRICTIONS",
    "ee_collision_trajectory",
    "compare_with_paper",
    "controller_model",
    "default_trace_every",
    "free_motion_false_alarms",
    "free_motion_trajectory",
    "link_collision_trajectory",
    "run_ee_collision",
    "run_link_collision",
    "summarize_ee_collision",
    "summarize_link_collision",
    "write_outputs",
]

ROBOT = "atlas_v5_left_arm"

#: Model error of the controller in the collision experiments, a fraction (0.1 = uniform factors within
#: +-10 %): the level the paper assumes for its simulated arm (Sec. III-C); the real Atlas model's error
#: is not stated as a level. On this arm the factors achieve a median relative error of g(q) of 1.2-3.2 %
#: and of M(q) of 1.1-2.2 % (model seeds 0-4): independent factors on many parameters partly cancel.
#: That is smaller than the real arm's (Table I: RMS torque errors of 3.6-4.6 Nm on the hydraulic joints
#: with the better model), so the collision results here do not include the real model's worst errors.
DEFAULT_MODEL_ERROR = 0.1


def controller_model(
    robot: RobotModel, model_error: float | None = None, model_seed: int = 0, model: RobotModel | None = None
) -> tuple[RobotModel, dict[str, object]]:
    """(the controller's model, its description): ``model`` if given, else ``robot`` with uniform errors
    within +-``model_error`` (None: :data:`DEFAULT_MODEL_ERROR`; seed ``model_seed``), the exact ``robot``
    at level 0.

    Raises:
        ConfigError: ``model`` given together with a non-zero ``model_error``; bad level or seed.
    """
    if model is not None:
        if model_error:
            raise ConfigError(f"model= is used as given; got model_error={model_error!r} as well (pass one of them)")
        if tuple(model.joint_names) != tuple(robot.joint_names):
            raise ConfigError(f"model has joints {list(model.joint_names)}; the plant has {list(robot.joint_names)}")
        return model, {"source": "given", "name": model.name}
    if model_error is None:
        model_error = DEFAULT_MODEL_ERROR
    if model_error == 0.0:
        return robot, {"source": "exact"}
    return perturb_model(robot, model_error, model_seed), {
        "source": "perturbed",
        "level": float(model_error),
        "seed": int(model_seed),
    }


@dataclass(frozen=True)
class CollisionSetting:
    """One run of Fig. 8: joint stiffness k_i [Nm/rad], observer gain k_o [1/s], threshold zeta [Nm], one
    level or one per joint (None: detection off), the reaction (a name of ``Controller(reaction=...)``:
    "gravity" = (13), "compliant", "none", ...) and, optionally, the gain of a second observer that detects
    (``detection_observer_gain`` [1/s], None: the first observer detects), and the observers' discretization
    (``"euler"``, the paper's, or ``"exact"``, stable at any gain); ``detection_friction_band`` [rad/s]: the
    detection observer subtracts the friction model in this velocity band (``Controller(detection_kappa_f=1)``;
    None: it follows kappa_f); ``detection_filter_gain`` [1/s]: the detection residual's second stage
    (``Controller(detection_filter_gain=)``; None: none); ``reaction_settings``: the reactions' (brake time, retract
    distance, ...; None: their defaults)."""

    name: str
    stiffness: float
    observer_gain: float = 5.0
    threshold: float | tuple[float, ...] | None = 11.0
    reaction: str = "gravity"
    damping_ratio: float = 0.7
    detection_observer_gain: float | None = None
    observer_discretization: str = "euler"
    detection_friction_band: float | None = None
    reaction_settings: ReactionSettings | None = None
    detection_filter_gain: float | None = None

    def controller(self, robot: RobotModel) -> Controller:
        """This setting's controller on the model ``robot`` (the controller's model, not the plant's)."""
        return Controller(
            robot,
            stiffness=experiment_stiffness(robot, self.stiffness, self.damping_ratio),
            damping_ratio=self.damping_ratio,
            observer_gain=self.observer_gain,
            detection_observer_gain=self.detection_observer_gain,
            threshold=self.threshold,
            reaction=self.reaction,
            observer_discretization=self.observer_discretization,
            **detection_friction(self.detection_friction_band),
            detection_filter_gain=self.detection_filter_gain,
            reaction_settings=self.reaction_settings,
        )


#: The three runs of Fig. 8.
EE_SETTINGS = (
    CollisionSetting("Stiff", stiffness=300.0, threshold=None, reaction="none"),
    CollisionSetting("Compliant", stiffness=100.0, threshold=None, reaction="none"),
    CollisionSetting("Coll.Det", stiffness=300.0, observer_gain=5.0, threshold=11.0, reaction="gravity"),
)

#: The run of Fig. 10.
LINK_SETTING = CollisionSetting("Coll.Det", stiffness=300.0, observer_gain=5.0, threshold=11.0, reaction="gravity")

# The end-effector collision: the forearm points forward, shz swings the hand towards the body's
# midline through a padded cinderblock standing on a table (joint values [rad], model order).
EE_START = np.array([0.55, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
EE_GOAL = np.array([-0.45, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
EE_MOVE_TIME = 6.0  # [s]: peak hand speed ~0.12 m/s, the paper's "moderate velocity (100 mm/s)"
EE_BLOCK = dict(position=(0.70, 0.225), table_height=0.585, mass=20.0)

#: Cinderblock variants of the demo (``block=`` of :func:`run_ee_collision`, ``--block`` of the CLI).
#: "paper" is the demo's default: a 0.39 x 0.19 x 0.19 m, 20 kg block, concrete on wood (friction 0.6);
#: the Stiff arm slides it ~6 cm. "tipping": the same mass, 0.29 m tall, on a table with friction 0.9
#: (a rough or rubber top): the friction holds the base and the hand's push acts higher above it, so the
#: Stiff arm tips the block over (tilt ~60 deg at the end, model/noise seeds 0-2) as in Fig. 7 b. Each change
#: alone is not enough (measured: friction 0.9 at 0.19 m tilts it 14 deg; 0.29 m at friction 0.6 slides
#: it). Compliant and Coll.Det show the same forces on both blocks (they do not reach the tipping load).
EE_BLOCKS: dict[str, dict[str, object]] = {
    "paper": dict(EE_BLOCK),
    "tipping": dict(EE_BLOCK, friction=0.9, size=(0.39, 0.19, 0.29)),
}


def ee_collision_trajectory(start: np.ndarray = EE_START, goal: np.ndarray = EE_GOAL) -> JointTrajectory:
    """Hold 0.5 s, move in EE_MOVE_TIME, hold 2 s at the goal."""
    return JointTrajectory(np.array([start, start, goal, goal]), np.array([0.5, EE_MOVE_TIME, 2.0]))


#: Free-motion trajectories for the false-alarm check: "demo" swings shz back and forth along the demo's
#: path (the other joints hold); "loaded" (alias "hydraulic" on Atlas) cycles through postures that move
#: the four joints with the largest gravity and friction load at once (on Atlas the hydraulic shz, shx,
#: ely, elx; hand speeds up to ~0.3 m/s), the friction-dominated motion the paper's threshold had to
#: tolerate. Each segment lasts EE_MOVE_TIME + 0.5 s. Other arms: :func:`free_motion_trajectory`.
FREE_MOTIONS = ("demo", "loaded", "hydraulic")
HYDRAULIC_WAYPOINTS = np.array(
    [
        [0.55, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0],
        [-0.45, -0.9, 1.2, 1.1, 0.0, 0.0, 0.0],
        [0.2, -0.5, 2.0, 0.6, 0.0, 0.0, 0.0],
        [-0.3, -1.2, 1.0, 1.9, 0.0, 0.0, 0.0],
    ]
)


def free_motion_trajectory(
    duration: float, motion: str = "demo", robot: RobotModel | None = None, *, seed: int | None = None
) -> JointTrajectory:
    """A trajectory of at least ``duration`` s that cycles through the waypoints of ``motion`` (see
    :data:`FREE_MOTIONS`), starting and ending each cycle at :data:`EE_START`.

    On another arm than Atlas (``robot``): "demo" swings the end effector as the demo does
    (:func:`~reflexarm.experiments.any_arm.ee_swing_plan`), "loaded" moves its four most loaded joints
    (:func:`~reflexarm.experiments.any_arm.loaded_waypoints`), starting at the swing's start (demo) or
    the arm's start posture; segments of EE_MOVE_TIME + 0.5 s or the swing's move time.

    ``seed`` (None: the fixed cycle) makes another log of the same motion: every cycle visits its
    waypoints in a seeded order, each moved by up to
    :data:`~reflexarm.experiments.free_motion_variation.FREE_MOTION_JITTER_RAD` (or 5 % of the joint's
    range, whichever is smaller; clipped to the range), with segment times scaled by 0.85-1.2. Tuning and
    held-out logs of one arm then differ in motion as well as in noise.
    """
    if motion not in FREE_MOTIONS:
        raise ConfigError(f"unknown free motion {motion!r}; choose one of: {', '.join(FREE_MOTIONS)}")
    seg = EE_MOVE_TIME + 0.5
    if robot is None or is_paper_arm(robot):
        start = EE_START
        cycle = [EE_GOAL] if motion == "demo" else list(HYDRAULIC_WAYPOINTS[1:])
    elif motion == "hydraulic":
        raise ConfigError(f"free motion 'hydraulic' names Atlas' hydraulic joints; on {robot.name!r} use 'loaded'")
    elif motion == "demo":
        plan = ee_swing_plan(robot)
        start, cycle, seg = plan.start, [plan.goal], max(seg, plan.move_time + 0.5)
    else:
        start = start_posture(robot)
        cycle = list(loaded_waypoints(robot, start))
    k = max(1, int(np.ceil(duration / (seg * (len(cycle) + 1)))))
    if seed is not None:
        return varied_cycles(np.asarray(start, float), np.asarray(cycle, float), seg, duration, seed, robot)
    way = [start]
    for _ in range(k):
        way += [*cycle, start]
    return JointTrajectory(np.array(way), np.full(len(way) - 1, seg))


def link_collision_trajectory() -> JointTrajectory:
    """A joint motion that swings the elbow sideways at ~50 mm/s (Fig. 9) and returns."""
    a = np.array([0.4, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
    b = np.array([-0.4, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
    return JointTrajectory(np.array([a, a, b, b]), np.array([1.0, 10.0, 2.0]))


#: The true arm's joint friction in the collision experiments (``plant_friction=``): the robot file's
#: (``frictionloss`` = Coulomb, ``damping`` = viscous), or none at all (both zero on every joint).
PLANT_FRICTIONS = ("file", "none")


def _true_friction(robot: RobotModel, plant_friction: str) -> CoulombViscousFriction | None:
    if plant_friction not in PLANT_FRICTIONS:
        raise ConfigError(f"unknown plant_friction {plant_friction!r}; choose one of: {', '.join(PLANT_FRICTIONS)}")
    return None if plant_friction == "file" else CoulombViscousFriction.zeros(robot.n)


def _block(block: str) -> dict[str, object]:
    if block not in EE_BLOCKS:
        raise ConfigError(f"unknown cinderblock variant {block!r}; choose one of: {', '.join(EE_BLOCKS)}")
    return EE_BLOCKS[block]


def run_ee_collision(
    setting: CollisionSetting,
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    model: RobotModel | None = None,
    block: str = "paper",
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
    robot: RobotModel | None = None,
    depth: float = 0.12,
    plant_friction: str = "file",
) -> Trace:
    """One run of the cinderblock experiment (Figs. 7-8).

    On Atlas (default) the paper's setting; on another ``robot`` the end effector swings as
    :func:`~reflexarm.experiments.any_arm.ee_swing_plan` derives and the block (variant ``block``) stands
    across its path, ``depth`` [m] deep (:func:`~reflexarm.experiments.any_arm.place_cinderblock`).

    Args:
        setting: one of :data:`EE_SETTINGS` (or your own).
        model_error: the controller's model errors, a fraction (None: :data:`DEFAULT_MODEL_ERROR`; see
            :func:`controller_model`).
        model_seed: seed of the model errors.
        model: the controller's model (e.g. identified); replaces the perturbed one.
        block: cinderblock variant, a key of :data:`EE_BLOCKS`.
        noise: sensor noise (default the paper's).
        seed: seed of the sensor noise.
        progress: show a progress bar.
        robot: the arm (plant's true model; default the built-in Atlas arm).
        depth: how deep the unobstructed end effector would run into the block [m] (not on Atlas).
        plant_friction: the true arm's joint friction: "file" (the robot file's frictionloss and damping)
            or "none" (no joint friction or damping at all: an arm that nothing but its controller stops;
            the controller's model is unchanged), see :data:`PLANT_FRICTIONS`.
    """
    robot = load_robot(ROBOT) if robot is None else robot
    ctrl_model, model_info = controller_model(robot, model_error, model_seed, model)
    placement: dict[str, object] = {}
    swing_joint = 0
    if is_paper_arm(robot):
        scene = Cinderblock(**_block(block))  # type: ignore[arg-type]
        traj = ee_collision_trajectory()
    else:
        plan = ee_swing_plan(robot)
        traj = plan.trajectory()
        # the variant's mass, friction and size; the position and table come from the placement
        variant = {k: v for k, v in _block(block).items() if k not in ("position", "table_height", "size")}
        size = tuple(float(x) for x in _block(block).get("size", (0.39, 0.19, 0.19)))  # type: ignore[attr-defined]
        placement = place_cinderblock(robot, traj, depth=depth, size=size)  # type: ignore[arg-type]
        kwargs = {k: v for k, v in placement.items() if k not in ("contact_time_s", "depth", "ee_height_m")}
        scene = Cinderblock(**kwargs, **variant)  # type: ignore[arg-type]
        placement = {**placement, **plan.describe()}
        swing_joint = plan.joint
    plant = Plant(robot, scene=scene, noise=noise, seed=seed, true_friction=_true_friction(robot, plant_friction))
    plant.reset(traj.waypoints[0])
    ctrl = setting.controller(ctrl_model)
    trace = run_fast(plant, ctrl, traj, traj.duration, progress=progress)  # compiled when it can
    trace.meta.update(
        {
            "experiment": "ee_collision",
            "plant_friction": plant_friction,
            "robot": robot.name,
            "swing_joint": swing_joint + 1,
            "placement": placement,
            "setting": asdict(setting),
            "controller_model": model_info,
            "block": block,
            "seed": seed,
            "tipped": bool(scene.tipped(plant)),
            "block_displacement": scene.displacement(plant).tolist(),
        }
    )
    trace.meta["contact_estimate"] = _contact_estimate(trace)
    return trace


#: The link collision's stick (``stick=`` of :func:`run_link_collision`, ``--stick`` of the CLI).
STICKS = ("pushed", "held")


def run_link_collision(
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    model: RobotModel | None = None,
    setting: CollisionSetting = LINK_SETTING,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
    robot: RobotModel | None = None,
    link: int | str | None = None,
    plant_friction: str = "file",
    stick: str = "pushed",
) -> Trace:
    """The elbow push of Figs. 9-10 with detection and reaction (13); arguments as :func:`run_ee_collision`
    (``plant_friction`` too).

    ``stick``: ``"pushed"`` (the paper's: the stick is pushed into the moving link at 50 mm/s for 1.5 s, and keeps
    coming after a detection), or ``"held"``: the stick stands still on the link's path
    (:func:`~reflexarm.experiments.link_push.held_stick_tip`) from the start of the move to the end of the run,
    and the moving link runs into it (a static obstacle: what a reaction can get away from).

    On another ``robot`` than Atlas (or with ``link`` on Atlas) the stick pushes ``link`` (1-based joint
    number whose link is pushed, or a link name; default mid-chain) while the arm swings it
    (:func:`~reflexarm.experiments.any_arm.link_push_plan`).
    """
    robot = load_robot(ROBOT) if robot is None else robot
    ctrl_model, model_info = controller_model(robot, model_error, model_seed, model)
    placement: dict[str, object] = {}
    if stick not in STICKS:
        raise ConfigError(f"unknown stick {stick!r}; choose one of: {', '.join(STICKS)}")
    if is_paper_arm(robot) and link is None:
        traj, body, t_start, standoff = link_collision_trajectory(), "l_larm", 5.0, 0.10
    else:
        plan = link_push_plan(robot, link)
        traj, body, t_start, standoff = plan.trajectory, plan.body, plan.t_start, plan.standoff
        placement = dict(plan.info)
    if stick == "held":  # it stands on the link's path from the start of the move (the link is still far)
        t_move = move_start(traj)
        tip, direction = held_stick_tip(robot, body, traj, t_move)
        placement.update({"held_stick_tip_m": tip.tolist(), "held_stick_from_s": t_move})
        scene = ElbowStick(body=body, t_start=t_move, speed=0.0, duration=traj.duration, direction=direction, tip=tip)
    else:
        scene = ElbowStick(body=body, t_start=t_start, standoff=standoff)
    plant = Plant(robot, scene=scene, noise=noise, seed=seed, true_friction=_true_friction(robot, plant_friction))
    plant.reset(traj.waypoints[0])
    ctrl = setting.controller(ctrl_model)
    trace = run_fast(plant, ctrl, traj, traj.duration, progress=progress)  # compiled when it can
    trace.meta.update(
        {
            "experiment": "link_collision",
            "stick": stick,
            "pushed_body": scene.body,
            "plant_friction": plant_friction,
            "robot": robot.name,
            "placement": placement,
            "setting": asdict(setting),
            "controller_model": model_info,
            "seed": seed,
        }
    )
    trace.meta["contact_estimate"] = _contact_estimate(trace)
    return trace


def model_torque(trace: Trace, robot: RobotModel | None = None) -> np.ndarray:
    """tau_mdl = M_hat(q) ddq + C_hat dq + g_hat from the measured motion (ddq by central differences of dq)."""
    robot = robot or load_robot(ROBOT)
    ddq = np.gradient(trace.dq, trace.t, axis=0)
    return np.array([robot.compute_inverse_dynamics(q, dq, a) for q, dq, a in zip(trace.q, trace.dq, ddq, strict=True)])


def free_motion_false_alarms(
    duration: float = 60.0,
    *,
    threshold: float = 11.0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
    model_error: float | None = None,
    model_seed: int = 0,
    model: RobotModel | None = None,
    motion: str = "demo",
    trace_path: str | None = None,
    robot: RobotModel | None = None,
    trace_every: int | None = None,
) -> dict[str, object]:
    """Run the demo trajectory back and forth without obstacle for ``duration`` s with detection on.

    Returns the number of detections (false alarms) and the largest |residual| per joint. The controller's
    model is chosen by ``model_error``/``model_seed``/``model`` as in :func:`run_ee_collision`; ``motion``
    picks the path (:func:`free_motion_trajectory`). The run keeps running statistics only
    (:func:`~reflexarm.sim.stream_fast`: the compiled loop, statistics folded in C++; separate detections,
    ticks per mode and fault, ticks above fractions of ``threshold`` per joint), in memory independent of
    ``duration``; ``trace_path`` (``.parquet``) also streams the trace to disk block by block: every
    ``trace_every``-th tick (default :func:`default_trace_every`: every tick up to
    :data:`FULL_TRACE_UP_TO_S`, every :data:`LONG_RUN_TRACE_EVERY`-th beyond).
    """
    robot = load_robot(ROBOT) if robot is None else robot
    ctrl_model, _model_info = controller_model(robot, model_error, model_seed, model)
    traj = free_motion_trajectory(duration, motion, robot)
    plant = Plant(robot, noise=noise, seed=seed)
    plant.reset(traj.waypoints[0])
    stiffness = experiment_stiffness(ctrl_model, 300.0)
    ctrl = Controller(ctrl_model, stiffness=stiffness, observer_gain=5.0, threshold=threshold, reaction="none")
    # running statistics only (the trace streamed to ``trace_path`` block by block if given): the memory
    # does not grow with the duration, so hours of free motion fit; the compiled loop unless it cannot
    from reflexarm.sim import stream_fast

    every = default_trace_every(duration) if trace_every is None else trace_every
    stats = stream_fast(plant, ctrl, traj, duration, path=trace_path, progress=progress, trace_every=every)
    return {
        "duration_s": stats.t_last,
        "false_alarm_ticks": stats.collision_ticks,
        "false_alarm_events": stats.collision_events,
        "max_abs_residual_Nm": stats.max_abs_residual.tolist(),
        "first_false_alarm_s": stats.first_collision_t,
        "fault_ticks": stats.fault_ticks,
        "modes": stats.modes,
        # for choosing zeta afterwards: ticks per joint at or above fractions of it (0.1 Nm resolution)
        "ticks_above_Nm": {f"{x:g}": stats.ticks_above(x).tolist() for x in threshold * np.array([0.5, 0.75, 1.0])},
        "trace_file": None if trace_path is None else str(trace_path),
        "trace_every_ticks": every if trace_path is not None else None,
        "robot": robot.name,
        "motion": motion,
        "loop": stats.loop,
    }


#: A free-motion trace keeps every tick up to this duration [s] (~0.41 MB per simulated second of the Atlas arm).
FULL_TRACE_UP_TO_S = 600.0
#: ... and every this many ticks beyond (10 Hz at 1 kHz: ~20 MB per simulated hour of the Atlas arm; the
#: statistics, the largest residuals and the histogram, are over every tick all the same).
LONG_RUN_TRACE_EVERY = 100


def default_trace_every(duration: float) -> int:
    """Ticks per written row of a free-motion trace of ``duration`` s: 1 up to :data:`FULL_TRACE_UP_TO_S`,
    :data:`LONG_RUN_TRACE_EVERY` beyond (a long run's trace stays small: ~20 MB per simulated hour)."""
    return 1 if duration <= FULL_TRACE_UP_TO_S else LONG_RUN_TRACE_EVERY


def _contact_estimate(trace: Trace) -> dict[str, object] | None:
    """Where and how hard the controller found the run's detected contact, in the tick (JSON-ready; the event's
    ``estimate``): None without a detection, without collision geometry, or if the run ended before it was in."""
    record = trace.meta.get("collision_event")
    return None if not record else record.get("estimate")  # type: ignore[no-any-return]
