"""The plant's sensors: the noisy measurement (q, dq, tau_m, wrist wrench, gravity) and the true external
torque and contact force, all read from the MuJoCo data of the last physics evaluation."""

from __future__ import annotations

import mujoco
import numpy as np

from reflexarm.errors import SimulationError
from reflexarm.signals import Measurement
from reflexarm.sim._kernels_lazy import kernels as _kernels

#: Noise samples are drawn in blocks of this many ticks (one ``Generator.uniform`` call per block).
_NOISE_BLOCK = 1024

_NO_SENSORS = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)


def step_sensing_last(m: mujoco.MjModel, d: mujoco.MjData, steps: int) -> None:
    """``steps`` physics steps with the sensors (and the post-constraint pass they need for cacc, cfrc_int,
    cfrc_ext) evaluated on the last one only: the plant reads them once per tick, after its last substep,
    and they feed nothing in the dynamics, so the state and the readings are the same to the bit; saves
    ~5 % of a 2-substep tick. The compiled loop (cpp/src/closed_loop.cpp) steps the same way."""
    if steps > 1:
        flags = int(m.opt.disableflags)
        m.opt.disableflags = flags | _NO_SENSORS
        try:
            mujoco.mj_step(m, d, steps - 1)
        finally:
            m.opt.disableflags = flags
    mujoco.mj_step(m, d)


class _PlantSensors:
    """What :class:`~reflexarm.sim.plant.Plant` reports: :meth:`measure`, :meth:`true_wrench`,
    :meth:`true_external_torque`, :meth:`ee_contact_force`. The attributes are set by ``Plant.__init__``
    and ``Plant.reset``."""

    n: int
    _data: mujoco.MjData
    _failed: str | None
    _noisy: bool
    _zero_noise: np.ndarray
    _rng: np.random.Generator
    _dim: int
    _levels: np.ndarray
    _noise_rows: np.ndarray
    _noise_i: int
    _qpos: np.ndarray
    _qvel: np.ndarray
    _tau: np.ndarray
    _gravity: np.ndarray
    _cinert: np.ndarray
    _cvel: np.ndarray
    _cacc: np.ndarray
    _cfrc_for_sensor: np.ndarray
    _cfrc_ext: np.ndarray
    _sensordata: np.ndarray
    _subtree_com: np.ndarray
    _site_xpos: np.ndarray
    _site_xmat: np.ndarray
    _cdof: np.ndarray
    _idx: np.ndarray
    _arm_bodies: np.ndarray
    _body_parent: np.ndarray
    _dof_body: np.ndarray
    _arm_dofs: np.ndarray
    _acc6: np.ndarray
    _load_bodies: np.ndarray

    # ------------------------------------------------------------------ sensors
    def _next_noise(self) -> np.ndarray:
        if self._noise_i >= self._noise_rows.shape[0]:
            self._noise_rows = self._rng.uniform(-1.0, 1.0, (_NOISE_BLOCK, self._dim)) * self._levels
            self._noise_i = 0
        row: np.ndarray = self._noise_rows[self._noise_i]
        self._noise_i += 1
        return row

    def _measurement_vector(self, noise: np.ndarray) -> np.ndarray:
        """A fresh (3n + 9,) vector: q, dq, tau_m, wrench (6), gravity (3), plus ``noise``."""
        out = np.empty(self._dim)
        _kernels.measurement(
            self._qpos,
            self._qvel,
            self._tau,
            self._gravity,
            self._cinert,
            self._cvel,
            self._cacc,
            self._cfrc_for_sensor,
            self._sensordata,
            self._subtree_com,
            self._site_xpos,
            self._site_xmat,
            self._idx,
            noise,
            out,
        )
        return out

    def measure(self) -> Measurement:
        """What the robot's sensors report now (with noise): q, dq, tau_m (the motor torque applied over the
        last control period, i.e. the previous command; 0 after reset), the load-compensated wrist wrench
        (environment on the tool, sensor frame, about the sensor origin) and gravity in the base frame."""
        if self._failed is not None:
            raise SimulationError(f"the plant failed earlier ({self._failed}); call reset() first")
        out = self._measurement_vector(self._next_noise() if self._noisy else self._zero_noise)
        n = self.n
        return Measurement(
            float(self._data.time),
            out[:n],
            out[n : 2 * n],
            out[2 * n : 3 * n],
            out[3 * n : 3 * n + 6],
            out[3 * n + 6 :],
        )

    def true_wrench(self) -> np.ndarray:
        """The wrist wrench of :meth:`measure` without noise (6,) [N, Nm]."""
        n = self.n
        return self._measurement_vector(self._zero_noise)[3 * n : 3 * n + 6]

    # ------------------------------------------------------------------ true external quantities
    def true_external_torque(self, out: np.ndarray | None = None) -> np.ndarray:
        """tau_ext (n,) [Nm]: sum over the arm's bodies of J^T F of every external force on them.

        The external wrenches are MuJoCo's ``cfrc_ext`` (contacts with scene objects, applied forces,
        equality constraints) of the last physics evaluation; ``J_b^T F_b`` is evaluated as the dot product
        of each dof's motion axis ``cdof`` with the wrenches summed over its subtree (both com-based about
        the same point, so this is exact). Internal forces (joint friction, joint limits) are not included.
        ``out``: optional (n,) array to write into (no allocation).
        """
        res = np.empty(self.n) if out is None else out
        _kernels.external_joint_torque(
            self._cfrc_ext,
            self._cdof,
            self._arm_bodies,
            self._body_parent,
            self._dof_body,
            self._arm_dofs,
            self._acc6,
            res,
        )
        return res

    def ee_contact_force(self, out: np.ndarray | None = None) -> np.ndarray:
        """Force (3,) [N], world frame, that the environment exerts on the bodies beyond the wrist sensor
        (contacts and applied forces, last physics evaluation). ``out``: optional (3,) array to write into."""
        res = np.empty(3) if out is None else out
        _kernels.sum_force(self._cfrc_ext, self._load_bodies, res)
        return res
