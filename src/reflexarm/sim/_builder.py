"""Building the plant's MuJoCo model from the robot's own file (private).

The MuJoCo model is compiled from the same URDF/MJCF file as the controller's Pinocchio model, then
completed with what the simulation needs: sites for the end-effector and sensor frames when the file
has none, the wrist force/torque sensors, the true joint friction and the scene's bodies. An arm cut
out of a larger robot (``robot.cut``) has the other joints frozen exactly as in the controller's model
(deleted, their bodies moved to the locked positions; see ``reflexarm.robots._cut``), and the joint
couplings left between arm joints (a URDF ``<mimic>``, an MJCF joint equality) are removed: the controller's
model drives every arm joint independently, and a note said so when the robot was loaded (see
``reflexarm.robots._coupling``).

Motors are ideal torque sources: the file's own actuators (position servos and the like, e.g. the
Menagerie arms' ``<general>`` servos) are removed, with the sensors that read them and the keyframes'
``ctrl``, and a :class:`~reflexarm.robots.RobotFileWarning` names them; so is MuJoCo's body gravity
compensation (``gravcomp``), an actuation trick the controller does itself. MJCF mesh files that are
absent are dropped with their geoms, as for URDF (see ``reflexarm.robots._mjcf``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.robots._coupling import drop_joint_equalities
from reflexarm.robots._cut import freeze_joints
from reflexarm.robots._mjcf import load_mjcf_spec
from reflexarm.robots._notes import warn_note
from reflexarm.robots._urdf import mujoco_urdf_spec, read_urdf
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

#: Collision bits shared by the plant and the scenes. The built-in arm uses contype=2, conaffinity=1:
#: its geoms never collide with each other (2 & 1 == 0) but collide with anything whose contype has
#: bit 1 (``CONTACT_ARM``). Static scenery (floor, table) and the hard cores of scene objects use bit 4
#: (``CONTACT_WORLD``) in both masks, so they touch each other but never the arm.
ARM_CONTYPE = 2
ARM_CONAFFINITY = 1
CONTACT_ARM = 1
CONTACT_WORLD = 4

#: Friction-loss constraint softness used instead of MuJoCo's default (solref 0.02 1, solimp 0.9 0.95):
#: with the default, a joint loaded below its Coulomb level mu_C creeps at ~5 % of mu_C * M^-1 * 1 s
#: (0.05 rad/s for elx of Atlas at 0.5 mu_C), which is no stiction at all. With impedance 0.9999 and the
#: fastest time constant MuJoCo accepts (2 x timestep) the creep falls to ~3e-6 rad/s, far below the
#: paper's position noise (3.4e-4 rad) over any experiment. Only applied where the file keeps MuJoCo's
#: defaults.
FRICTION_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
_DEFAULT_SOLREF = (0.02, 1.0)
_DEFAULT_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)

SENSOR_FORCE = "reflexarm_wrist_force"
SENSOR_TORQUE = "reflexarm_wrist_torque"


@dataclass
class BuildInfo:
    """Names the plant needs after compiling: the arm joints and the frame sites."""

    joint_names: list[str]
    ee_site: str
    sensor_site: str
    is_urdf: bool
    notes: list[str] = field(default_factory=list)


def load_spec(path: Path) -> tuple[mujoco.MjSpec, bool]:
    """Parse a robot file into an MjSpec; URDF files are rewritten first (see ``robots/_urdf.py``: joints
    to undefined links dropped, ``package://`` meshes resolved or dropped, ``.dae`` meshes read, visuals
    discarded, fixed links kept as bodies, no inertia from geometry). The notes were given when the
    RobotModel was loaded."""
    if not path.is_file():
        raise ModelError(f"robot file {str(path)!r} does not exist")
    is_urdf = path.suffix.lower() == ".urdf"
    if not is_urdf:
        return load_mjcf_spec(path)[0], False
    return mujoco_urdf_spec(read_urdf(path))[0], is_urdf


def _frame_pose(robot: RobotModel, frame: str, q: np.ndarray) -> pin.SE3:
    model = robot.pin_model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[model.getFrameId(frame)].copy()


def _body_for_frame(spec: mujoco.MjSpec, robot: RobotModel, frame: str) -> str:
    """The MuJoCo body a Pinocchio frame is rigidly attached to."""
    model = robot.pin_model
    fid = model.getFrameId(frame)
    seen = set()
    f = model.frames[fid]
    while True:
        if spec.body(f.name) is not None and f.name != "world":
            return str(f.name)
        parent = int(f.parentFrame)
        if parent in seen or parent == 0:
            break
        seen.add(parent)
        f = model.frames[parent]
    joint = int(model.frames[fid].parentJoint)
    if joint > 0:
        mj_joint = spec.joint(model.names[joint])
        if mj_joint is not None:
            return str(mj_joint.parent.name)
    raise ModelError(
        f"frame {frame!r} of {str(robot.source)!r} is not attached to a moving body MuJoCo knows; "
        "use a frame on the arm"
    )


def _ensure_sites(spec: mujoco.MjSpec, robot: RobotModel, joint_names: list[str]) -> dict[str, str]:
    """Sites for the ee and sensor frames: the file's own site of that name, else one added at the
    Pinocchio frame placement relative to the body it hangs on (computed at the zero configuration)."""
    sites: dict[str, str] = {}
    missing = [f for f in dict.fromkeys((robot.ee_frame, robot.sensor_frame)) if spec.site(f) is None]
    for f in (robot.ee_frame, robot.sensor_frame):
        if f not in missing:
            sites[f] = f
    if not missing:
        return sites
    try:
        model = spec.compile()
    except Exception as e:
        raise ModelError(f"MuJoCo cannot compile robot file {str(robot.source)!r}: {e}") from e
    data = mujoco.MjData(model)
    q = np.zeros(robot.n)
    for i, name in enumerate(joint_names):
        q[i] = model.qpos0[model.jnt_qposadr[model.joint(name).id]]
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    for frame in missing:
        body = _body_for_frame(spec, robot, frame)
        bid = model.body(body).id
        body_pose = pin.SE3(data.xmat[bid].reshape(3, 3).copy(), data.xpos[bid].copy())
        rel = body_pose.inverse() * _frame_pose(robot, frame, q)
        name = frame  # MuJoCo names are unique per object type: a body may share the frame's name
        quat = pin.Quaternion(rel.rotation)
        spec.body(body).add_site(
            name=name,
            pos=np.asarray(rel.translation, dtype=float),
            quat=np.array([quat.w, quat.x, quat.y, quat.z]),
            size=[0.01, 0.01, 0.01],
        )
        sites[frame] = name
    return sites


def _joint_names(spec: mujoco.MjSpec, robot: RobotModel) -> list[str]:
    names = robot.joint_names
    missing = [j for j in names if spec.joint(j) is None]
    if missing:
        mj_names = [j.name for j in spec.joints]
        raise ModelError(
            f"robot file {str(robot.source)!r}: MuJoCo has no joint(s) {missing} that Pinocchio found; "
            f"MuJoCo joints are: {mj_names}"
        )
    return list(names)


def _remove_actuation(spec: mujoco.MjSpec, path: Path) -> list[str]:
    """Remove the file's actuators (and what refers to them) and body gravity compensation; say which."""
    notes = []
    actuators = [a.name or f"#{i}" for i, a in enumerate(spec.actuators)]
    if actuators:
        names = {a.name for a in spec.actuators}
        for sensor in list(spec.sensors):
            if sensor.objtype == mujoco.mjtObj.mjOBJ_ACTUATOR or (
                sensor.type == mujoco.mjtSensor.mjSENS_ACTUATORFRC and sensor.objname in names
            ):
                spec.delete(sensor)
        for actuator in list(spec.actuators):
            spec.delete(actuator)
        for key in spec.keys:
            key.ctrl = []
            key.act = []
        notes.append(
            f"robot file {str(path)!r}: the plant removed the file's {len(actuators)} actuator(s) "
            f"{actuators}; its motors are ideal torque sources driven by the controller's command"
        )
    gravcomp = [b.name for b in spec.bodies if b.gravcomp != 0.0]
    if gravcomp:
        for body in spec.bodies:
            body.gravcomp = 0.0
        notes.append(f"robot file {str(path)!r}: the plant removed body gravity compensation (gravcomp) on {gravcomp}")
    return notes


def _set_friction(
    spec: mujoco.MjSpec, joint_names: list[str], friction: CoulombViscousFriction | None, timestep: float
) -> None:
    if friction is not None and friction.n != len(joint_names):
        raise ModelError(f"true_friction has {friction.n} joints; the robot has {len(joint_names)}")
    solref = (2.0 * timestep, 1.0)
    for i, name in enumerate(joint_names):
        joint = spec.joint(name)
        if friction is not None:
            joint.frictionloss = float(friction.coulomb[i])
            # MuJoCo 4 stores damping as (linear, polynomial terms...): the override is purely viscous
            damping = np.zeros_like(np.atleast_1d(np.asarray(joint.damping, dtype=float)))
            damping[0] = float(friction.viscous[i])
            joint.damping = damping if damping.size > 1 else float(damping[0])
        if np.allclose(joint.solref_friction, _DEFAULT_SOLREF) and np.allclose(joint.solimp_friction, _DEFAULT_SOLIMP):
            joint.solref_friction = solref
            joint.solimp_friction = list(FRICTION_SOLIMP)


#: Name prefixes of the actuators that carry the smooth joint friction (see :func:`add_smooth_friction`).
SMOOTH_COULOMB_PREFIX = "reflexarm_smooth_coulomb_"
SMOOTH_VISCOUS_PREFIX = "reflexarm_smooth_viscous_"


def add_smooth_friction(spec: mujoco.MjSpec, joint_names: list[str], friction: CoulombViscousFriction) -> None:
    """The passive joint torque ``-(mu_C clip(dq / band, -1, 1) + d_v dq)`` as MuJoCo actuators (no stiction).

    Two force-only actuators per joint with zero gain (``ctrl`` does nothing) and an affine velocity bias:
    the Coulomb part ``-(mu_C / band) dq`` clamped to ``[-mu_C, mu_C]`` (``forcerange``), which is exactly
    ``-mu_C clip(dq / band, -1, 1)``, and the viscous part ``-d_v dq``. MuJoCo evaluates them in C at every
    physics step, and the plant's ``implicitfast`` integrator treats their velocity slope implicitly. The
    former Python callback added the same torque explicitly, which inside the band (slope mu_C / band, up to
    515 Nms/rad) is unstable on the light wrist joints at 0.5 ms: held at half its Coulomb level, where the
    law gives dq = band / 2 = 0.01 rad/s, wry2 chattered at a mean 1.2 rad/s (std 1.7); here it moves at
    0.0100 rad/s. Joints with mu_C = 0 (or d_v = 0) get no Coulomb (viscous) actuator.
    """
    if friction.n != len(joint_names):
        raise ModelError(f"smooth_friction has {friction.n} joints; the robot has {len(joint_names)}")
    band = float(friction.velocity_band)
    for i, name in enumerate(joint_names):
        mu, dv = float(friction.coulomb[i]), float(friction.viscous[i])
        for prefix, slope, limit in ((SMOOTH_COULOMB_PREFIX, mu / band, mu), (SMOOTH_VISCOUS_PREFIX, dv, 0.0)):
            if slope == 0.0:
                continue
            act = spec.add_actuator(name=f"{prefix}{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.gainprm[0] = 0.0
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.biasprm[:3] = [0.0, 0.0, -slope]
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
            if limit > 0.0:
                act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
                act.forcerange = [-limit, limit]
            else:
                act.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE


def build_robot_spec(
    robot: RobotModel,
    *,
    true_friction: CoulombViscousFriction | None,
    timestep: float,
    smooth_friction: CoulombViscousFriction | None = None,
) -> tuple[mujoco.MjSpec, BuildInfo]:
    """The robot part of the plant's MjSpec (the scene is added by the caller)."""
    if robot.source is None:
        raise ModelError(f"robot {robot.name!r} has no source file; the plant builds MuJoCo from the same file")
    path = Path(robot.source)
    spec, is_urdf = load_spec(path)
    joint_names = _joint_names(spec, robot)
    notes = _remove_actuation(spec, path)
    if robot.cut is not None:
        freeze_joints(spec, robot.cut.locked, path)  # the same joints at the same positions as the model
    drop_joint_equalities(spec)  # couplings of arm joints: independent joints in the model (see _coupling.py)
    for note in notes:
        warn_note(note, stacklevel=4)
    if is_urdf:
        # URDF has no collision masks: give the arm the built-in convention (no self-collision).
        for geom in spec.geoms:
            geom.contype = ARM_CONTYPE
            geom.conaffinity = ARM_CONAFFINITY
    _set_friction(spec, joint_names, true_friction, timestep)
    if smooth_friction is not None:
        add_smooth_friction(spec, joint_names, smooth_friction)
    # Scene objects at rest may sleep (MuJoCo islands: a resting cinderblock costs nothing until the arm
    # touches it, which wakes it); the arm itself never sleeps, its torques change every tick.
    spec.joint(joint_names[0]).parent.sleep = mujoco.mjtSleepPolicy.mjSLEEP_NEVER
    spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    # Never let MuJoCo silently reset the state on NaN/huge accelerations (it would restart from qpos0
    # mid-run); the bad values stay and the plant's own check turns them into a SimulationError.
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    sites = _ensure_sites(spec, robot, joint_names)
    sensor_site = sites[robot.sensor_frame]
    spec.add_sensor(
        name=SENSOR_FORCE, type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=sensor_site
    )
    spec.add_sensor(
        name=SENSOR_TORQUE, type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=sensor_site
    )
    spec.option.timestep = timestep
    return spec, BuildInfo(joint_names, sites[robot.ee_frame], sensor_site, is_urdf, notes)
