"""The retract that does not wait for the isolation (``ReactionSettings.retract_waits_for_estimate`` False, the
default): it is planned on the detecting tick from the detection residual, so the isolation's budget
(``isolation_points_per_tick``) decides only when the event record has the contact, never what the arm does.

The tick-by-tick comparison with the independent oracle is in ``tests/test_controller_oracle.py``
(``test_tick_isolation_and_retract_equal_the_plain_isolator``); here the property the default budget rests on.
Fails on the retract that waits for the estimate (the code before this change): its torques depend on the budget.
"""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.control import Controller, ReactionSettings
from reflexarm.signals import Measurement, Reference

DT = 1e-3
ONSET = 100


def _run(robot, geometry, contact, points_per_tick: int, waits: bool, ticks: int = 800):
    """Torques, modes and the event of a static arm at the contact's posture, the contact's J_c^T f from tick 100."""
    settings = ReactionSettings(isolation_points_per_tick=points_per_tick, retract_waits_for_estimate=waits,
                                brake_duration=0.04, retract_speed=0.5, rest_time=0.1)  # fmt: skip
    ctrl = Controller(robot, threshold=11.0, reaction="retract", detection_observer_gain=200.0,
                      observer_discretization="exact", reaction_settings=settings,
                      contact_geometry=geometry)  # fmt: skip
    g = robot.compute_gravity(contact.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    taus, modes = [], []
    for k in range(ticks):
        tau_m = g - (contact.torque if k >= ONSET else 0.0)
        cmd = ctrl.step(Measurement((k + 1) * DT, contact.q, zeros, tau_m, np.zeros(6), gravity),
                        Reference(contact.q, zeros, zeros))  # fmt: skip
        taus.append(cmd.tau.copy())
        modes.append(cmd.mode)
    return np.array(taus), modes, ctrl.event


@pytest.mark.parametrize("waits", [False, True])
def test_the_budget_sets_when_the_estimate_is_in_and_not_what_the_arm_does_unless_the_retract_waits(
    panda_contact, waits
):
    """Budgets of 1 and 100000 units a tick: the estimate comes in > 50 ms later with 1; the retract that does not
    wait is retracting from the detecting tick and commands the same torques, bit for bit, with either; the one that
    waits brakes on the detecting tick and its torques differ by more than 1 Nm (so the first assertion fails on the
    code before this change, whose retract always waited)."""
    robot, geometry, contact = panda_contact
    slow = _run(robot, geometry, contact, 1, waits)
    fast = _run(robot, geometry, contact, 100000, waits)
    for _taus, modes, event in (slow, fast):
        assert event is not None and event.estimate is not None and event.reaction == "retract"
        k_det = int(round(event.t_detect / DT)) - 1
        assert modes[k_det] == ("braking" if waits else "retracting")
    # the estimate comes in later with the smaller budget, in both
    assert slow[2].t_estimated > fast[2].t_estimated + 0.05
    assert slow[2].t_detect == fast[2].t_detect
    if waits:  # the retract waits for the estimate: the smaller budget brakes longer, so the torques differ
        assert np.abs(slow[0] - fast[0]).max() > 1.0  # [Nm]
    else:  # the same retract, tick for tick, bit for bit
        np.testing.assert_array_equal(slow[0], fast[0])
        assert slow[1] == fast[1]
        np.testing.assert_array_equal(slow[2].q_target, fast[2].q_target)
