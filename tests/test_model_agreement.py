"""The controller's model (Pinocchio) and the plant (MuJoCo) are two readings of one robot file: they must
agree on the rigid-body dynamics of eq. (1) and on the frames the controller uses.

Tolerance: 1e-9 (absolute, in kg m^2, Nm, m, rad/s) for quantities of order 1..100. Both libraries
compute the same exact expressions in double precision (relative round-off ~1e-15); any modelling
difference (a dropped root placement, an inertia in another frame, armature, a joint axis sign) shows
up at 1e-3 or more, so 1e-9 separates the two by six orders of magnitude.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from reflexarm.robots import builtin_robots, load_robot
from reflexarm.sim import Plant, SensorNoise

ATOL = 1e-9
N_STATES = 100

BUILTINS = [
    pytest.param(name, marks=pytest.mark.skipif(not b.path.exists(), reason=f"{b.file} not written yet"))
    for name, b in sorted(builtin_robots().items())
]


def _random_states(robot, m, rng, n_states=N_STATES):
    lo = np.where(np.isfinite(robot.lower_limit), robot.lower_limit, -np.pi)
    hi = np.where(np.isfinite(robot.upper_limit), robot.upper_limit, np.pi)
    for _ in range(n_states):
        yield rng.uniform(lo, hi), rng.normal(0.0, 1.5, robot.n)


def check_agreement(robot, plant, n_states=N_STATES, seed=0):
    """Worst absolute differences of M, g, C dq and the sensor-frame Jacobian over random states."""
    m = plant.model
    d = mujoco.MjData(m)  # a private data: the plant's own state is not touched
    dofs = plant._arm_dofs
    qadr = plant._qadr_arr
    site = plant._sensor_site
    M_mj = np.zeros((m.nv, m.nv))
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    worst = {"M": 0.0, "g": 0.0, "Cdq": 0.0, "J": 0.0}
    for q, dq in _random_states(robot, m, np.random.default_rng(seed), n_states):
        d.qpos[:] = m.qpos0
        d.qpos[qadr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M_mj)
        g_mj = d.qfrc_bias[dofs].copy()
        mujoco.mj_jacSite(m, d, jacp, jacr, site)
        R = d.site_xmat[site].reshape(3, 3)
        J_mj = np.vstack([R.T @ jacp[:, dofs], R.T @ jacr[:, dofs]])  # LOCAL: expressed in the site frame
        d.qvel[dofs] = dq
        mujoco.mj_forward(m, d)
        cdq_mj = d.qfrc_bias[dofs] - g_mj
        M_pin = robot.compute_mass_matrix(q)
        g_pin = robot.compute_gravity(q)
        cdq_pin = robot.compute_nonlinear_effects(q, dq) - g_pin
        worst["M"] = max(worst["M"], float(np.abs(M_pin - M_mj[np.ix_(dofs, dofs)]).max()))
        worst["g"] = max(worst["g"], float(np.abs(g_pin - g_mj).max()))
        worst["Cdq"] = max(worst["Cdq"], float(np.abs(cdq_pin - cdq_mj).max()))
        worst["J"] = max(worst["J"], float(np.abs(robot.compute_frame_jacobian(q) - J_mj).max()))
    return worst


@pytest.mark.parametrize("name", BUILTINS)
def test_pinocchio_and_mujoco_agree_on_builtin(name):
    robot = load_robot(name)
    plant = Plant(robot, noise=SensorNoise.none())
    worst = check_agreement(robot, plant)
    for key, err in worst.items():
        assert err <= ATOL, f"{name}: max |{key}_pinocchio - {key}_mujoco| = {err:.3g} over {N_STATES} states"


@pytest.mark.parametrize("name", BUILTINS)
def test_plant_friction_is_the_files(name):
    """Default true friction = the file's frictionloss/damping = what RobotModel read from the same file."""
    robot = load_robot(name)
    plant = Plant(robot, noise=SensorNoise.none())
    np.testing.assert_array_equal(plant.true_friction.coulomb, robot.friction.coulomb)
    np.testing.assert_array_equal(plant.true_friction.viscous, robot.friction.viscous)
