"""External forces applied to the plant's bodies (through ``xfrc_applied``) and body poses."""

from __future__ import annotations

import mujoco
import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError


class _AppliedForce:
    __slots__ = ("body", "force", "point_local")

    def __init__(self, body: int, force: np.ndarray, point_local: np.ndarray) -> None:
        self.body = body
        self.force = force
        self.point_local = point_local


class _PlantForces:
    """Applied forces and poses of :class:`~reflexarm.sim.plant.Plant`: :meth:`apply_external_force`,
    :meth:`clear_external_force`, :meth:`body_pose`, :meth:`ee_position`. The attributes are set by
    ``Plant.__init__``."""

    _model: mujoco.MjModel
    _data: mujoco.MjData
    _ee_site: int
    _ee_body: int
    _xfrc: np.ndarray
    _forces: dict[int, _AppliedForce]
    _next_force: int

    # ------------------------------------------------------------------ applied forces and poses
    def _body_id(self, name: str | int | None) -> int:
        m = self._model
        if name is None:
            return self._ee_body
        if isinstance(name, (int, np.integer)):
            if not 0 < int(name) < m.nbody:
                raise ConfigError(f"body id {name} out of range 1..{m.nbody - 1}")
            return int(name)
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            names = [m.body(i).name for i in range(m.nbody)]
            raise ConfigError(f"unknown body {name!r}; bodies are: {', '.join(names)}")
        return int(bid)

    def body_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), quaternion (w, x, y, z)) of a body in the world, at the last physics evaluation
        (exact at the current state for bodies without joints, e.g. mocap bodies)."""
        bid = self._body_id(name)
        return self._data.xpos[bid].copy(), self._data.xquat[bid].copy()

    def ee_position(self) -> np.ndarray:
        """World position of the end-effector site (3,) [m] (last physics evaluation)."""
        return np.array(self._data.site_xpos[self._ee_site])

    def apply_external_force(
        self, force_world: npt.ArrayLike, point_world: npt.ArrayLike | None = None, body: str | int | None = None
    ) -> int:
        """Apply a force [N] (world frame, constant until cleared) at a point moving with ``body``.

        ``body`` defaults to the body carrying the end-effector site; ``point_world`` (world coordinates at
        the time of the call) defaults to the end-effector site position, or to the centre of mass of
        ``body`` when a body is named. The point is stored in the body's
        frame, so it moves with the body; the force keeps its world direction. It is applied through
        ``xfrc_applied`` (force at the body's COM plus the moment (p - com) x f, refreshed each tick).
        Returns a handle for :meth:`clear_external_force`.
        """
        f = np.asarray(force_world, dtype=float)
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ConfigError(f"force_world must be a finite 3-vector [N]; got {force_world!r}")
        bid = self._body_id(body)
        d = self._data
        if point_world is None:
            p = d.site_xpos[self._ee_site].copy() if body is None else d.xipos[bid].copy()
        else:
            p = np.asarray(point_world, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ConfigError(f"point_world must be a finite 3-vector [m]; got {point_world!r}")
        R = d.xmat[bid].reshape(3, 3)
        dx = p - d.xpos[bid]
        local = (R[0] * dx[0] + R[1] * dx[1]) + R[2] * dx[2]  # R^T dx as the compiled loop sums it
        handle = self._next_force
        self._next_force += 1
        self._forces[handle] = _AppliedForce(bid, f.copy(), local)
        self._apply_forces()
        return handle

    def clear_external_force(self, handle: int | None = None) -> None:
        """Remove one applied force (by handle) or all of them."""
        if handle is None:
            self._forces.clear()
        elif handle in self._forces:
            del self._forces[handle]
        else:
            raise ConfigError(f"no applied force with handle {handle!r}; active: {sorted(self._forces)}")
        self._apply_forces()

    def _apply_forces(self) -> None:
        d = self._data
        xfrc = self._xfrc
        xfrc[:] = 0.0
        # R l and R^T dx are written as element-wise sums, not `@`: numpy's matrix products go to BLAS, whose
        # kernels fuse multiply-adds differently per CPU; these sums are what cpp/src/closed_loop.cpp computes
        for f in self._forces.values():
            b = f.body
            R, loc = d.xmat[b].reshape(3, 3), f.point_local
            p = d.xpos[b] + ((R[:, 0] * loc[0] + R[:, 1] * loc[1]) + R[:, 2] * loc[2])
            xfrc[b, :3] += f.force
            xfrc[b, 3:] += np.cross(p - d.xipos[b], f.force)
