"""Real data: Gaz et al.'s Franka Emika Panda excitation log (see ../shared/reference/panda_gaz2019).

Identify on the first 60 % of the samples, validate on the last 40 %. For scale on the same last 40 %:
the model Gaz et al. published scores 0.373 Nm pooled RMSE, a plain least-squares fit with Coulomb +
viscous friction and offsets 0.287 Nm; the torque's content above 10 Hz alone is about 0.26 Nm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from reflexarm.ident import (
    LogRepairWarning,
    RobotLog,
    identify_dynamics,
    mass_matrix_margin,
    preprocess_log,
    project_physically_consistent,
    validate_model,
)
from reflexarm.robots import load_robot

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "panda_gaz2019"

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"real Panda log not available at {DATA}")

#: The target pooled validation RMSE over the 7 joints [Nm].
TARGET_POOLED_RMSE = 0.30


@pytest.fixture(scope="module")
def panda_log():
    t = np.loadtxt(DATA / "exciting_traj_time.txt")
    q = np.loadtxt(DATA / "exciting_traj_positions.txt").reshape(-1, 7)
    dq = np.loadtxt(DATA / "exciting_traj_velocity.txt").reshape(-1, 7)
    tau = np.loadtxt(DATA / "exciting_traj_torques.txt").reshape(-1, 7)
    with pytest.warns(LogRepairWarning) as record:
        log = RobotLog.from_arrays(t, q, dq, tau, source="panda_gaz2019")
    messages = [str(w.message) for w in record]
    split_time = float(t[int(round(0.6 * t.size))])  # first raw sample of the last 40 %
    return log, split_time, messages


def test_the_real_log_is_repaired_and_says_so(panda_log):
    log, _, messages = panda_log
    assert any("dropped 1,131 rows that exactly repeat the previous row" in m for m in messages)
    # the host's stamps jitter by more than half a period (0.7 to 15.5 ms steps): re-timing onto a grid would
    # move samples by more than half a period, so the log keeps its own stamps and its notes say why
    kept = next(m for m in log.notes if "kept the log's own time stamps" in m)
    assert "period 1 ms, the median step" in kept and "on one tick" in kept
    assert log.is_uniform is False and np.all(np.diff(log.t) > 0)


@pytest.mark.slow  # ~30 s alone, 150 s on a loaded 2-core machine (the consistency projection)
def test_identify_on_60_percent_validate_on_40_percent(panda_log):
    log, split_time, _ = panda_log
    robot = load_robot("panda")
    states = preprocess_log(log)
    result = identify_dynamics(robot, states.select(states.t < split_time), method="combined", offset=True)
    assert result.base.n_base == 43
    val = validate_model(result, robot, log.select(log.t >= split_time), states=states)
    assert val.pooled_rmse <= TARGET_POOLED_RMSE, f"pooled RMSE {val.pooled_rmse:.4f} Nm, per joint {val.rmse}"
    # every joint is explained: RMSE well below the torque's own spread
    assert np.all(val.nrmse < 0.25), val.nrmse
    # the physically consistent projection costs little on held-out data and gives a usable model
    consistent = project_physically_consistent(result, robot)
    val_c = validate_model(consistent, robot, log.select(log.t >= split_time), states=states)
    assert val_c.pooled_rmse <= TARGET_POOLED_RMSE
    assert mass_matrix_margin(consistent.to_robot_model(robot)) > 0
