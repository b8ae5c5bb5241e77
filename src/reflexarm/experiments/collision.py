"""Collision experiments of Sec. III-A/B: end-effector collision with a padded cinderblock (Figs. 7-8)
and a link collision at the elbow (Figs. 9-10), simulated on the built-in Atlas arm."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from reflexarm.control import Controller
from reflexarm.robots import RobotModel, load_robot
from reflexarm.sim import (
    PAPER_NOISE,
    Cinderblock,
    ElbowStick,
    JointTrajectory,
    Plant,
    SensorNoise,
    Trace,
    run_closed_loop,
)

__all__ = [
    "CollisionSetting",
    "EE_SETTINGS",
    "LINK_SETTING",
    "ee_collision_trajectory",
    "free_motion_false_alarms",
    "link_collision_trajectory",
    "run_ee_collision",
    "run_link_collision",
    "summarize_ee_collision",
    "summarize_link_collision",
]

ROBOT = "atlas_v5_left_arm"

#: Window of the moving average that defines the quasi-static contact force [s]: long against the
#: impact transient (tens of ms), short against the seconds the arm pushes.
QUASI_STATIC_WINDOW_S = 0.5

#: Contact is counted when the environment pushes the tool with more than this [N] (above the wrist
#: sensor's noise band of +-2.3 N, and well below the tens of newtons of a collision).
CONTACT_FORCE_N = 5.0


@dataclass(frozen=True)
class CollisionSetting:
    """One run of Fig. 8: joint stiffness k_i [Nm/rad], observer gain k_o [1/s], threshold zeta [Nm]
    (None: detection off), and the reaction ("gravity" = (13), "none")."""

    name: str
    stiffness: float
    observer_gain: float = 5.0
    threshold: float | None = 11.0
    reaction: str = "gravity"
    damping_ratio: float = 0.7

    def controller(self, robot: RobotModel) -> Controller:
        return Controller(
            robot,
            stiffness=self.stiffness,
            damping_ratio=self.damping_ratio,
            observer_gain=self.observer_gain,
            threshold=self.threshold,
            reaction=self.reaction,
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


def ee_collision_trajectory(start: np.ndarray = EE_START, goal: np.ndarray = EE_GOAL) -> JointTrajectory:
    """Hold 0.5 s, move in EE_MOVE_TIME, hold 2 s at the goal."""
    return JointTrajectory(np.array([start, start, goal, goal]), np.array([0.5, EE_MOVE_TIME, 2.0]))


def link_collision_trajectory() -> JointTrajectory:
    """A joint motion that swings the elbow sideways at ~50 mm/s (Fig. 9) and returns."""
    a = np.array([0.4, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
    b = np.array([-0.4, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
    return JointTrajectory(np.array([a, a, b, b]), np.array([1.0, 10.0, 2.0]))


def run_ee_collision(
    setting: CollisionSetting,
    *,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
) -> Trace:
    """One run of the cinderblock experiment (Figs. 7-8)."""
    robot = load_robot(ROBOT)
    scene = Cinderblock(**EE_BLOCK)  # type: ignore[arg-type]
    plant = Plant(robot, scene=scene, noise=noise, seed=seed)
    traj = ee_collision_trajectory()
    plant.reset(traj.sample(0.0).q_d)
    ctrl = setting.controller(robot)
    trace = run_closed_loop(plant, ctrl, traj, traj.duration, progress=progress)
    trace.meta.update(
        {
            "experiment": "ee_collision",
            "setting": asdict(setting),
            "seed": seed,
            "tipped": bool(scene.tipped(plant)),
            "block_displacement": scene.displacement(plant).tolist(),
        }
    )
    return trace


def _first_index(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def summarize_ee_collision(trace: Trace) -> dict[str, object]:
    """Peak contact force, first contact, detection time and delay, block displacement, tipped."""
    f = np.linalg.norm(trace.f_ext_ee, axis=1)
    w = max(1, int(round(QUASI_STATIC_WINDOW_S / float(np.median(np.diff(trace.t))))))
    f_quasi_static = np.convolve(f, np.ones(w) / w, mode="valid")
    i_contact = _first_index(f > CONTACT_FORCE_N)
    i_det = _first_index(trace.collision)
    t_contact = None if i_contact is None else float(trace.t[i_contact])
    t_det = None if i_det is None else float(trace.t[i_det])
    tail = trace.t >= trace.t[-1] - 1.0
    disp = np.asarray(trace.meta.get("block_displacement", [np.nan, np.nan, np.nan]), dtype=float)
    return {
        "run": trace.meta["setting"]["name"],
        "peak_force_N": float(f.max()),
        "quasi_static_force_N": float(f_quasi_static.max()),
        "final_force_N": float(f[tail].mean()),
        "first_contact_s": t_contact,
        "detection_s": t_det,
        "detection_delay_s": None if (t_det is None or t_contact is None) else t_det - t_contact,
        "detected_joints": list(np.flatnonzero(trace.collided[i_det]).tolist()) if i_det is not None else [],
        "block_displacement_m": float(np.linalg.norm(disp[:2])),
        "block_tipped": bool(trace.meta.get("tipped", False)),
        "final_q1_error_rad": float(abs(trace.q_d[-1, 0] - trace.q[-1, 0])),
    }


def run_link_collision(*, noise: SensorNoise = PAPER_NOISE, seed: int = 0, progress: bool = False) -> Trace:
    """The elbow push of Figs. 9-10 with detection and reaction (13)."""
    robot = load_robot(ROBOT)
    traj = link_collision_trajectory()
    scene = ElbowStick(body="l_larm", t_start=5.0)
    plant = Plant(robot, scene=scene, noise=noise, seed=seed)
    plant.reset(traj.sample(0.0).q_d)
    ctrl = LINK_SETTING.controller(robot)
    trace = run_closed_loop(plant, ctrl, traj, traj.duration, progress=progress)
    trace.meta.update({"experiment": "link_collision", "setting": asdict(LINK_SETTING), "seed": seed})
    return trace


def model_torque(trace: Trace, robot: RobotModel | None = None) -> np.ndarray:
    """tau_mdl = M_hat(q) ddq + C_hat dq + g_hat from the measured motion (ddq by central differences of dq)."""
    robot = robot or load_robot(ROBOT)
    ddq = np.gradient(trace.dq, trace.t, axis=0)
    return np.array([robot.compute_inverse_dynamics(q, dq, a) for q, dq, a in zip(trace.q, trace.dq, ddq, strict=True)])


def summarize_link_collision(trace: Trace) -> dict[str, object]:
    """Contact start on the elbow, detection time, delay and the joints that crossed first."""
    tau_ext = np.abs(trace.tau_ext).max(axis=1)
    i_contact = _first_index(tau_ext > 1.0)
    i_det = _first_index(trace.collision)
    t_contact = None if i_contact is None else float(trace.t[i_contact])
    t_det = None if i_det is None else float(trace.t[i_det])
    return {
        "run": "link collision",
        "contact_start_s": t_contact,
        "detection_s": t_det,
        "detection_delay_s": None if (t_det is None or t_contact is None) else t_det - t_contact,
        "detected_joints": list(np.flatnonzero(trace.collided[i_det]).tolist()) if i_det is not None else [],
        "peak_external_torque_Nm": float(tau_ext.max()),
    }


def free_motion_false_alarms(
    duration: float = 60.0,
    *,
    threshold: float = 11.0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    progress: bool = False,
) -> dict[str, float]:
    """Run the demo trajectory back and forth without obstacle for ``duration`` s with detection on.

    Returns the number of detections (false alarms) and the largest |residual| per joint.
    """
    robot = load_robot(ROBOT)
    k = int(np.ceil(duration / (2 * EE_MOVE_TIME + 1.0)))
    way = [EE_START]
    for _ in range(k):
        way += [EE_GOAL, EE_START]
    durs = [EE_MOVE_TIME + 0.5] * (len(way) - 1)
    traj = JointTrajectory(np.array(way), np.array(durs))
    plant = Plant(robot, noise=noise, seed=seed)
    plant.reset(EE_START)
    ctrl = Controller(robot, stiffness=300.0, observer_gain=5.0, threshold=threshold, reaction="none")
    trace = run_closed_loop(plant, ctrl, traj, duration, progress=progress)
    return {
        "duration_s": float(trace.t[-1]),
        "false_alarm_ticks": int(trace.collision.sum()),
        "max_abs_residual_Nm": np.abs(trace.residual).max(axis=0).tolist(),
    }


def write_outputs(out: Path, name: str, traces: Sequence[Trace], rows: Sequence[dict[str, object]]) -> None:
    """Save each trace (npz) and the summary table (JSON) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    for tr in traces:
        tr.save(out / f"{name}_{str(tr.meta['setting']['name']).replace('.', '').lower()}.npz")
    (out / f"{name}_summary.json").write_text(json.dumps(list(rows), indent=2))
