"""efc-step measures the joint that carries the load, says which, and plots it (issue 18 item 7)."""

from __future__ import annotations

import warnings

import matplotlib
import numpy as np
import pytest

from gen3_like import GEN3_TIP, write_gen3_like_urdf
from reflexarm.experiments.compensation import CompensationSetup, true_robot
from reflexarm.experiments.efc_step import efc_step
from reflexarm.experiments.plots import efc_step_figure

matplotlib.use("Agg")

#: Gen3-like posture: joint 2 tilts the arm forward 0.6 rad, so the 50 N step loads joints 2, 4 and 6
#: (parallel, horizontal axes) and leaves joint 1 (vertical) with nothing but the lever of small offsets.
GEN3_POSTURE = (0.0, 0.6, 0.0, 1.2, 0.0, 0.8, 0.0)


@pytest.fixture(scope="module")
def gen3_step(tmp_path_factory):
    path = write_gen3_like_urdf(tmp_path_factory.mktemp("gen3"), rounded_pi=False)
    setup = CompensationSetup(
        robot=str(path), robot_options=(("tip", GEN3_TIP),), posture=GEN3_POSTURE, t_off=2.0, duration=2.5
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return efc_step(setup, seed=0), setup


@pytest.mark.slow  # four 2.5 s runs on the plant
def test_the_loaded_joint_is_the_one_with_the_largest_external_torque(gen3_step):
    res, setup = gen3_step
    # reference: the plant's own external torque (MuJoCo's J^T f of the applied step), averaged here
    robot = true_robot(setup)
    tr = res.traces["no DC"]
    on = (tr.t >= setup.load_window[0]) & (tr.t < setup.load_window[1])
    expected = int(np.argmax(np.abs(tr.tau_ext[on].mean(axis=0))))
    assert res.joint == expected != 0, (res.joint, res.summary["tau_ext_Nm"])
    assert res.summary["loaded_joint"] == expected + 1
    assert res.summary["loaded_joint_name"] == robot.joint_names[expected]
    # joint 1 carries (almost) nothing: under 5 % of the loaded joint's torque
    tau = np.abs(res.summary["tau_ext_Nm"])
    assert tau[0] < 0.05 * tau[expected], tau
    by = {r["run"]: r for r in res.rows}
    assert by["no DC"]["tau_ext_loaded_Nm"] == pytest.approx(res.summary["tau_ext_Nm"][expected], rel=1e-12)
    ratio = abs(by["DC+EFC"]["residual_loaded_Nm"]) / abs(by["DC"]["residual_loaded_Nm"])
    assert res.summary["efc_vs_dc_residual_loaded"] == pytest.approx(ratio)


@pytest.mark.slow
def test_the_figure_shows_the_loaded_joint(gen3_step):
    res, _ = gen3_step
    fig = efc_step_figure(res)
    j = res.joint
    residual_axis = fig.axes[2]
    np.testing.assert_array_equal(residual_axis.lines[0].get_ydata(), res.traces["no DC"].residual[:, j])
    assert f"{j + 1}" in residual_axis.get_ylabel() and f"{j + 1}" in fig.axes[0].get_ylabel()
