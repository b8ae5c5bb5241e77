"""Plant: the *true* arm, simulated in MuJoCo from the same robot file as the controller's model."""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError, ModelError, SimulationError
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.loader import load_robot
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim import _kernel_layout
from reflexarm.sim._builder import SENSOR_FORCE, SENSOR_TORQUE, BuildInfo, build_robot_spec
from reflexarm.sim._kernels_lazy import kernels as _kernels
from reflexarm.sim._plant_forces import _AppliedForce, _PlantForces
from reflexarm.sim._plant_sensors import _PlantSensors, step_sensing_last
from reflexarm.sim.noise import PAPER_NOISE, SensorNoise
from reflexarm.sim.scene import Scene

__all__ = ["Plant"]

#: A state whose velocity norm exceeds this [rad/s or m/s] is treated as diverged.
MAX_SPEED = 1e3

ExtraTorque = Callable[[np.ndarray, np.ndarray, float], npt.ArrayLike]


class Plant(_PlantSensors, _PlantForces):
    """The simulated arm: MuJoCo rigid-body dynamics, true friction, scene contacts and noisy sensors.

    The MuJoCo model is compiled from ``robot.source`` (the same file the Pinocchio model was read from),
    completed with the wrist force/torque sensor and the scene. Motors are ideal torque sources: the
    commanded torque goes to ``qfrc_applied`` unchanged and is held over the control period. The file's own
    actuators (position servos etc.) and body ``gravcomp`` are removed, with a ``RobotFileWarning`` naming
    them (listed in :attr:`notes`).

    Timing: :meth:`step` advances ``control_period`` in ``control_period / timestep`` physics substeps.
    Positions and velocities in :meth:`measure` are those at :attr:`time`. Force quantities (the wrist
    wrench, :meth:`true_external_torque`, :meth:`ee_contact_force`) come from the last physics evaluation,
    i.e. the state one substep (0.5 ms by default) earlier under the torque just applied: a sensor
    latency of one substep, and all three are mutually exact.

    Args:
        robot: a :class:`RobotModel` or the name of a built-in robot.
        scene: a :class:`Scene` or a sequence of scenes (added to the model in order).
        noise: sensor noise levels; default :data:`PAPER_NOISE`. Use ``SensorNoise.none()`` for exact
            measurements.
        seed: seed of the noise generator; :meth:`reset` restarts the noise sequence from it.
        timestep: physics step [s]. Two 0.5 ms substeps per 1 ms tick by default, measured against one 1 ms
            step: the demo contact and link runs detect at the same tick either way, but with 1 ms the dry
            friction's stiction creeps twice as fast (its constraint time constant is 2 x timestep: ely at
            0.9 mu_C, 1.1e-4 instead of 5.6e-5 rad/s) and the Fig. 12 steady state moves by 3-6 % (no-DC EE
            displacement 75.8 mm at 1 ms, 73.6 at 0.5 ms, 73.2 at 0.25 ms; EFC/no-DC 0.973, 0.948, 0.947):
            0.5 ms is converged to ~0.6 %, 1 ms is not, so the physics keeps the two substeps.
        control_period: period of :meth:`step` [s], an integer multiple of ``timestep``.
        true_friction: joint friction of the true arm (MuJoCo ``frictionloss`` = Coulomb mu_C [Nm],
            ``damping`` = viscous d_v [Nms/rad]); default: what the file says (for Atlas: Table I).
        extra_joint_torque: ``f(q, dq, t) -> (n,)`` extra passive joint torque [Nm] added to the motor
            torque at every physics substep (e.g. a Stribeck or stiction law the model lacks). A Python
            call per substep: prefer ``smooth_friction`` for that law.
        smooth_friction: an extra joint friction without stiction, ``-(mu_C clip(dq / band, -1, 1) +
            d_v dq)`` (the controller library's smooth sign), evaluated by MuJoCo at every physics step
            (actuators with an affine velocity bias, see ``_builder.add_smooth_friction``): no Python per
            substep, and the compiled loop plays it as it is. Usually given with ``true_friction`` zero.

    Raises:
        ModelError: the file cannot be loaded into MuJoCo (message names the file).
        ConfigError: bad timing or noise arguments.
    """

    def __init__(
        self,
        robot: RobotModel | str | os.PathLike[str],
        *,
        scene: Scene | Sequence[Scene] | None = None,
        noise: SensorNoise | None = None,
        seed: int = 0,
        timestep: float = 5e-4,
        control_period: float = 1e-3,
        true_friction: CoulombViscousFriction | None = None,
        extra_joint_torque: ExtraTorque | None = None,
        smooth_friction: CoulombViscousFriction | None = None,
    ) -> None:
        if not isinstance(robot, RobotModel):
            robot = load_robot(robot)
        self.robot = robot
        self.n = robot.n
        self.timestep, self.control_period, self.substeps = _check_timing(timestep, control_period)
        self._check_arguments(scene, noise, seed, true_friction, extra_joint_torque, smooth_friction)
        info = self._compile(true_friction)
        self._map_indices(info)
        self._cache_views()
        self._forces: dict[int, _AppliedForce] = {}
        self._next_force = 0
        self._failed: str | None = None
        self._tick = 0
        # one run at a time (in_use): MuJoCo's data stepped by two threads at once crashes the process
        self._user_lock = threading.Lock()
        self._user: str | None = None  # who runs the plant now ("... in thread 'name'")
        self._user_thread: int | None = None
        self.reset(robot.home)

    def _check_arguments(
        self,
        scene: Scene | Sequence[Scene] | None,
        noise: SensorNoise | None,
        seed: int,
        true_friction: CoulombViscousFriction | None,
        extra_joint_torque: ExtraTorque | None,
        smooth_friction: CoulombViscousFriction | None,
    ) -> None:
        """The noise, seed, friction and scene arguments, checked (ConfigError naming the argument) and kept."""
        if noise is None:
            noise = PAPER_NOISE
        if not isinstance(noise, SensorNoise):
            raise ConfigError(f"noise must be a SensorNoise; got {type(noise).__name__}")
        self.noise = noise
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ConfigError(f"seed must be an integer; got {seed!r}")
        self.seed = int(seed)
        if true_friction is not None and not isinstance(true_friction, CoulombViscousFriction):
            raise ConfigError(f"true_friction must be a CoulombViscousFriction; got {type(true_friction).__name__}")
        if extra_joint_torque is not None and not callable(extra_joint_torque):
            raise ConfigError(f"extra_joint_torque must be callable f(q, dq, t); got {extra_joint_torque!r}")
        self._extra = extra_joint_torque
        if smooth_friction is not None and not isinstance(smooth_friction, CoulombViscousFriction):
            raise ConfigError(f"smooth_friction must be a CoulombViscousFriction; got {type(smooth_friction).__name__}")
        self.smooth_friction = smooth_friction
        if scene is None:
            scenes: list[Scene] = []
        elif isinstance(scene, Scene):
            scenes = [scene]
        else:
            scenes = list(scene)
            for s in scenes:
                if not isinstance(s, Scene):
                    raise ConfigError(f"scene must be a Scene or a sequence of Scenes; got {type(s).__name__}")
        self.scenes = scenes

    def _compile(self, true_friction: CoulombViscousFriction | None) -> BuildInfo:
        """The MuJoCo model of the file with the wrist sensor and the scenes, and its data; the build's info."""
        robot, scenes, smooth_friction = self.robot, self.scenes, self.smooth_friction
        spec, info = build_robot_spec(
            robot, true_friction=true_friction, timestep=self.timestep, smooth_friction=smooth_friction
        )
        for s in scenes:
            try:
                s.build(spec, robot)
            except (ConfigError, SimulationError):
                raise
            except Exception as e:
                raise SimulationError(f"scene {type(s).__name__} failed to build: {e}") from e
        try:
            self._model = spec.compile()
        except Exception as e:
            raise ModelError(f"MuJoCo cannot compile the plant of {str(robot.source)!r} with its scene: {e}") from e
        self._spec = spec
        self._data = mujoco.MjData(self._model)
        self.is_urdf = info.is_urdf
        #: What the build removed from the file (actuators, gravcomp), each also given as a RobotFileWarning.
        self.notes = tuple(info.notes)
        return info

    def _map_indices(self, info: BuildInfo) -> None:
        """Index maps from the arm's joints (in the Pinocchio order), sites and bodies into the MuJoCo model."""
        m, robot = self._model, self.robot
        jids = np.array([m.joint(j).id for j in info.joint_names])
        bad = [info.joint_names[i] for i, j in enumerate(jids) if m.jnt_type[j] not in (2, 3)]
        if bad:
            raise ModelError(f"robot file {str(robot.source)!r}: joints {bad} are not hinge/slide joints in MuJoCo")
        self._qadr = _as_index(m.jnt_qposadr[jids])
        self._vadr = _as_index(m.jnt_dofadr[jids])
        self._arm_dofs = np.asarray(m.jnt_dofadr[jids], dtype=np.int64)
        self._qadr_arr = np.asarray(m.jnt_qposadr[jids], dtype=np.int64)
        self._ee_site = m.site(info.ee_site).id
        self._sensor_site = m.site(info.sensor_site).id
        self._ee_body = int(m.site_bodyid[self._ee_site])
        sensor_body = int(m.site_bodyid[self._sensor_site])
        self._load_bodies = _subtree(m, sensor_body)
        self._physical_sensor = bool(m.body_jntnum[sensor_body] == 0 and m.body_dofnum[sensor_body] == 0)
        self._com_ref_body = int(m.body_rootid[sensor_body])
        self._force_adr = int(m.sensor_adr[m.sensor(SENSOR_FORCE).id])
        self._torque_adr = int(m.sensor_adr[m.sensor(SENSOR_TORQUE).id])
        first_arm_body = int(m.jnt_bodyid[jids[0]])
        self._arm_bodies = _subtree(m, first_arm_body)
        gravity_off = int(m.opt.disableflags) & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
        self._gravity = np.zeros(3) if gravity_off else np.array(m.opt.gravity, dtype=float)

    def _cache_views(self) -> None:
        """Preallocated buffers and cached views into MjData (they share memory with it)."""
        m, n, noise = self._model, self.n, self.noise
        d = self._data
        self._qpos, self._qvel, self._qfrc = d.qpos, d.qvel, d.qfrc_applied
        self._xfrc = d.xfrc_applied
        self._cinert, self._cvel, self._cacc = d.cinert, d.cvel, d.cacc
        self._cfrc_int, self._cfrc_ext = d.cfrc_int, d.cfrc_ext
        self._sensordata = d.sensordata
        self._site_xpos, self._site_xmat = d.site_xpos, d.site_xmat
        self._subtree_com = d.subtree_com
        self._cfrc_for_sensor = d.cfrc_int if self._physical_sensor else d.cfrc_ext
        self._cdof = d.cdof
        self._body_parent = np.asarray(m.body_parentid, dtype=np.int64)
        self._dof_body = np.asarray(m.dof_bodyid, dtype=np.int64)
        self._acc6 = np.zeros((m.nbody, 6))
        self._tau = np.zeros(n)
        self._dim = 3 * n + 9
        self._zero_noise = np.zeros(self._dim)
        self._idx = np.zeros(_kernel_layout.IDX_HEADER + 2 * n + self._load_bodies.size, dtype=np.int64)
        self._idx[_kernel_layout.IDX_N] = n
        self._idx[_kernel_layout.IDX_NLOAD] = self._load_bodies.size
        self._idx[_kernel_layout.IDX_FORCE] = self._force_adr
        self._idx[_kernel_layout.IDX_TORQUE] = self._torque_adr
        self._idx[_kernel_layout.IDX_PHYSICAL] = int(self._physical_sensor)
        self._idx[_kernel_layout.IDX_COM_BODY] = self._com_ref_body
        self._idx[_kernel_layout.IDX_SITE] = self._sensor_site
        self._idx[_kernel_layout.IDX_HEADER :] = np.concatenate([self._qadr_arr, self._arm_dofs, self._load_bodies])
        self._levels = np.concatenate(
            [
                np.full(n, noise.q),
                np.full(n, noise.dq),
                np.full(n, noise.tau_m),
                np.full(3, noise.force),
                np.full(3, noise.torque),
                np.full(3, noise.gravity),
            ]
        )
        self._noisy = not noise.is_zero

    # ------------------------------------------------------------------ facts
    @property
    def model(self) -> mujoco.MjModel:
        """The compiled MuJoCo model (advanced use; changing it changes the true world)."""
        return self._model

    @property
    def data(self) -> mujoco.MjData:
        """The MuJoCo data (advanced use)."""
        return self._data

    @property
    def time(self) -> float:
        """Simulation time [s]."""
        return float(self._data.time)

    @property
    def q(self) -> np.ndarray:
        """True joint positions (n,) [rad] (a copy)."""
        return self._qpos[self._qadr].copy()

    @property
    def dq(self) -> np.ndarray:
        """True joint velocities (n,) [rad/s] (a copy)."""
        return self._qvel[self._vadr].copy()

    @property
    def tau(self) -> np.ndarray:
        """Motor torque currently applied (n,) [Nm] (a copy)."""
        return self._tau.copy()

    @property
    def joint_names(self) -> list[str]:
        return self.robot.joint_names

    @property
    def true_friction(self) -> CoulombViscousFriction:
        """Joint friction of the plant (MuJoCo frictionloss, damping)."""
        m = self._model
        return CoulombViscousFriction(
            np.array(m.dof_frictionloss[self._arm_dofs]), np.array(m.dof_damping[self._arm_dofs])
        )

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description (for ``Trace.meta``)."""
        return {
            "robot": self.robot.name,
            "robot_file": str(self.robot.source),
            "timestep": self.timestep,
            "control_period": self.control_period,
            "seed": self.seed,
            "noise": self.noise.as_dict(),
            "true_friction": {
                "coulomb": self.true_friction.coulomb.tolist(),
                "viscous": self.true_friction.viscous.tolist(),
            },
            "extra_joint_torque": None if self._extra is None else getattr(self._extra, "__name__", repr(self._extra)),
            "smooth_friction": None
            if self.smooth_friction is None
            else {
                "coulomb": self.smooth_friction.coulomb.tolist(),
                "viscous": self.smooth_friction.viscous.tolist(),
                "velocity_band": self.smooth_friction.velocity_band,
            },
            "scene": [s.describe() for s in self.scenes],
        }

    # ------------------------------------------------------------------ state
    def reset(
        self, q0: npt.ArrayLike | None = None, dq0: npt.ArrayLike | None = None, *, seed: int | None = None
    ) -> None:
        """Put the arm at ``q0`` (default: the robot's home) with velocity ``dq0`` (default 0), the scene at
        its initial state, time 0, no applied forces, zero torque; restart the noise sequence from
        ``seed`` (default: the plant's seed).

        Raises:
            SimulationError: another thread runs the plant now (:meth:`in_use`); reset it after that run.
        """
        self._check_user("reset()")
        n = self.n
        q = _state_vector(self.robot.home if q0 is None else q0, n, "q0")
        v = np.zeros(n) if dq0 is None else _state_vector(dq0, n, "dq0")
        m, d = self._model, self._data
        mujoco.mj_resetData(m, d)
        self._qpos[self._qadr] = q
        self._qvel[self._vadr] = v
        self._tau[:] = 0.0
        self._forces.clear()
        self._failed = None
        self._tick = 0
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
                raise ConfigError(f"seed must be an integer; got {seed!r}")
            self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._noise_rows = np.zeros((0, self._dim))
        self._noise_i = 0
        for s in self.scenes:
            s.reset(self)
        mujoco.mj_forward(m, d)

    def step(self, tau: npt.ArrayLike) -> None:
        """Apply motor torque ``tau`` (n,) [Nm], held constant, for one control period.

        Raises:
            SimulationError: non-finite ``tau`` (names the joints), or the state diverged (NaN/inf or a
                speed above ``MAX_SPEED``); the plant then refuses to step until :meth:`reset`.
        """
        if self._user_thread is not None and self._user_thread != threading.get_ident():
            self._check_user("step()")
        if self._failed is not None:
            raise SimulationError(f"the plant failed earlier ({self._failed}); call reset() first")
        t = np.asarray(tau, dtype=float)
        if t.shape != (self.n,):
            raise SimulationError(f"tau must have shape ({self.n},); got {t.shape}")
        if not _kernels.set_torque(t, self._arm_dofs, self._tau, self._qfrc) < math.inf:
            bad = [self.robot.joint_names[i] for i in np.flatnonzero(~np.isfinite(t))]
            if bad:
                raise SimulationError(f"non-finite motor torque on joint(s) {bad}: {t.tolist()}; not applied")
            raise SimulationError(f"motor torque too large to be physical: {t.tolist()}; not applied")
        for s in self.scenes:
            s.update(self)
        if self._forces:
            self._apply_forces()
        m, d = self._model, self._data
        t_end = d.time + self.control_period
        if self._extra is None:
            step_sensing_last(m, d, self.substeps)
        else:
            for _ in range(self.substeps):
                extra = np.asarray(self._extra(self.q, self.dq, float(d.time)), dtype=float)
                if extra.shape != (self.n,) or not float(extra @ extra) < math.inf:
                    self._failed = f"extra_joint_torque returned {extra.tolist()!r} at t = {d.time:.4f} s"
                    raise SimulationError(f"{self._failed}; expected a finite ({self.n},) array")
                self._qfrc[self._vadr] = t + extra
                mujoco.mj_step(m, d)
        self._tick += 1
        vv = _kernels.sum_squares(self._qvel)
        if not vv < MAX_SPEED * MAX_SPEED or d.time < t_end - 0.5 * self.timestep:
            self._fail(vv)

    # ------------------------------------------------------------------ one user at a time
    @contextmanager
    def in_use(self, what: str) -> Iterator[None]:
        """Hold the plant for one run (``what`` names it in the errors of other users).

        While held, another run (any thread) is refused, and :meth:`reset` / :meth:`step` from another thread
        raise: MuJoCo's data stepped or reset by two threads at once crashes the process. The closed loops
        (Python and compiled) hold their plant for the whole run; use one Plant per thread.

        Raises:
            SimulationError: the plant is already in use (the message says by what, in which thread).
        """
        if not self._user_lock.acquire(blocking=False):
            raise SimulationError(
                f"this Plant is in use by {self._user or 'another run'}; {what} cannot run on it at the same time "
                "(one run per plant: make a Plant per thread)"
            )
        self._user = f"{what} in thread {threading.current_thread().name!r}"
        self._user_thread = threading.get_ident()
        try:
            yield
        finally:
            self._user = None
            self._user_thread = None
            self._user_lock.release()

    def _check_user(self, call: str) -> None:
        """SimulationError if another thread holds the plant (:meth:`in_use`)."""
        user, owner = self._user, self._user_thread
        if owner is not None and owner != threading.get_ident():
            raise SimulationError(
                f"{call} from thread {threading.current_thread().name!r} while this Plant is in use by {user}; "
                "wait for that run to end (one run per plant: make a Plant per thread)"
            )

    def _fail(self, vv: float) -> None:
        d = self._data
        warnings = (
            ("positions (qpos)", mujoco.mjtWarning.mjWARN_BADQPOS),
            ("velocities (qvel)", mujoco.mjtWarning.mjWARN_BADQVEL),
            ("accelerations (qacc)", mujoco.mjtWarning.mjWARN_BADQACC),
        )
        what = [label for label, w in warnings if d.warning[int(w)].number > 0]
        if what:
            reason = f"MuJoCo found NaN/inf/huge values in {', '.join(what)}"
        elif not math.isfinite(vv):
            reason = "the velocity became NaN/inf"
        else:
            reason = f"a speed of {math.sqrt(vv):.3g} exceeds {MAX_SPEED:g} rad/s or m/s"
        self._failed = f"simulation diverged near t = {self._tick * self.control_period:.4f} s: {reason}"
        raise SimulationError(self._failed + "; check the controller gains and the torque command")


def _check_timing(timestep: float, control_period: float) -> tuple[float, float, int]:
    for name, value in (("timestep", timestep), ("control_period", control_period)):
        if not isinstance(value, (int, float, np.floating)) or not math.isfinite(value) or value <= 0:
            raise ConfigError(f"{name} must be a positive number of seconds; got {value!r}")
    ratio = control_period / timestep
    substeps = round(ratio)
    if substeps < 1 or abs(ratio - substeps) > 1e-9 * ratio:
        raise ConfigError(
            f"control_period ({control_period!r} s) must be an integer multiple of timestep ({timestep!r} s); "
            f"got a ratio of {ratio:.6g}"
        )
    return float(timestep), float(control_period), int(substeps)


def _state_vector(value: npt.ArrayLike, n: int, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a numeric ({n},) array; got {value!r}") from e
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be a finite ({n},) array; got shape {arr.shape}: {arr.tolist()}")
    return arr


def _as_index(idx: np.ndarray) -> slice | np.ndarray:
    """A slice when the indices are contiguous and increasing (views and fast assignment), else the array."""
    idx = np.asarray(idx, dtype=np.intp)
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _subtree(m: mujoco.MjModel, root: int) -> np.ndarray:
    """Body ids of the subtree rooted at ``root`` (MuJoCo orders parents before children)."""
    inside = np.zeros(m.nbody, dtype=bool)
    inside[root] = True
    for b in range(root + 1, m.nbody):
        inside[b] = inside[m.body_parentid[b]]
    return np.flatnonzero(inside).astype(np.int64)
