"""Seeded fuzz test of Controller.step (issue 8): 10^5 closed-loop ticks over both shipped arms and the
switch configurations, a third of them corrupted (NaN/inf/huge values, wrong shapes and types, bad time
stamps, other dtypes). Asserted on every tick: a finite torque within the limits, no exception but the
package's own, the observer exactly unchanged by a rejected tick, no false alarm; and at the end, a push
detected at the same tick as by a fresh controller."""

from __future__ import annotations

import numpy as np
import pytest

from controller_checks import detected_as_by_a_fresh_controller
from pinsim import RigidBodyPlant
from reflexarm.control import Controller
from reflexarm.errors import ReflexArmError, SignalError
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot
from reflexarm.signals import Measurement, Reference

TICKS = 10_000  # per (arm, configuration): 2 arms x 5 configurations = 10^5 ticks
P_BAD = 0.3
SIGNALS = ("q", "dq", "tau_m", "wrench", "gravity", "q_d", "dq_d", "ddq_d")
CONFIGS = {
    "detection": dict(kappa_f=0, kappa_eps=0, kappa_ext=0),
    "DC+friction": dict(kappa_f=1, kappa_eps=1, kappa_ext=0),
    "DC+EFC": dict(kappa_f=0, kappa_eps=1, kappa_ext=1),
    "all, two observers": dict(kappa_f=1, kappa_eps=1, kappa_ext=1, detection_observer_gain=25.0),
    "detection, two observers": dict(kappa_f=0, kappa_eps=0, kappa_ext=0, detection_observer_gain=25.0),
}


class FrictionPlant(RigidBodyPlant):
    """The exact rigid-body plant plus the model's own joint friction (so kappa_f = 1 is exact too)."""

    def __init__(self, robot: RobotModel, **kw: object) -> None:
        super().__init__(robot, **kw)  # type: ignore[arg-type]
        self.friction = robot.friction

    def _f(self, t, q, dq, tau):  # type: ignore[no-untyped-def]
        return super()._f(t, q, dq, tau - self.friction.compute_torque(dq))


def fuzz_model(name: str) -> RobotModel:
    # a tenth of the nominal Coulomb friction over a wide velocity band keeps the friction torque a
    # non-stiff term for the RK4 plant at 0.5 ms (the lightest wrist would need 20x smaller steps)
    robot = load_robot(name)
    f = robot.friction
    return robot.with_friction(CoulombViscousFriction(0.1 * f.coulomb, f.viscous, velocity_band=0.5))


def corrupt(rng, m: Measurement, r: Reference, last_t: float):
    """A corrupted copy of (m, r) and what the controller must do with it: "fault", "raise" or "accept"."""
    kind = ["value", "value", "time", "shape", "type", "dtype"][rng.integers(6)]
    fields = {**m._asdict(), **r._asdict()}
    if kind == "value":
        name = SIGNALS[rng.integers(len(SIGNALS))]
        arr = np.array(fields[name], dtype=float)
        huge = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(4, 300)
        arr[rng.integers(arr.size)] = [np.nan, np.inf, -np.inf, huge][rng.integers(4)]
        fields[name] = arr
        expect = "fault"
    elif kind == "time":
        fields["t"] = [np.nan, last_t, last_t - rng.uniform(1e-6, 1.0), -np.inf][rng.integers(4)]
        expect = "fault"
    elif kind == "shape":
        name = SIGNALS[rng.integers(len(SIGNALS))]
        arr = np.asarray(fields[name])
        options = [arr[:-1], np.append(arr, 0.0), arr[None, :], np.zeros(0)]
        fields[name] = options[rng.integers(len(options))]
        expect = "raise"
    elif kind == "type":
        name = SIGNALS[rng.integers(len(SIGNALS))]
        arr = np.asarray(fields[name])
        options = [arr.astype(complex), arr.astype(str), np.full(arr.shape, None, dtype=object), arr.astype(bool), None]
        fields[name] = options[rng.integers(len(options))]
        expect = "raise"
    else:  # other dtypes and lists of good values are converted and accepted
        name = SIGNALS[rng.integers(len(SIGNALS))]
        arr = np.asarray(fields[name])
        fields[name] = arr.astype(np.float32) if rng.random() < 0.5 else arr.tolist()
        expect = "accept"
    mm = Measurement(*(fields[k] for k in Measurement._fields))
    rr = Reference(*(fields[k] for k in Reference._fields))
    return mm, rr, expect


def sine(q0: np.ndarray, amp: float = 0.2, w: float = 2 * np.pi * 0.5):
    def sample(t: float) -> Reference:
        s, c = np.sin(w * t), np.cos(w * t)
        return Reference(q0 + amp * s, amp * w * c * np.ones_like(q0), -amp * w * w * s * np.ones_like(q0))

    return sample


@pytest.mark.slow
@pytest.mark.parametrize("config", list(CONFIGS))
@pytest.mark.parametrize("arm", ["atlas_v5_left_arm", "panda"])
def test_no_input_disables_or_misleads_the_controller(arm, config):
    robot = fuzz_model(arm)
    kw = CONFIGS[config]

    def make() -> Controller:
        return Controller(robot, stiffness=150, observer_gain=5, threshold=11, reaction="gravity", **kw)

    ctrl = make()
    limit = ctrl.torque_limit
    assert np.all(np.isfinite(limit))
    plant = FrictionPlant(robot, substeps=2)
    plant.reset(robot.home)
    ref_of = sine(robot.home)
    rng = np.random.default_rng([8, len(arm), len(config)])
    counts = {"accept": 0, "fault": 0, "raise": 0}
    tau = np.zeros(robot.n)
    last_t = -np.inf
    for k in range(TICKS):
        m = plant.measure()
        r = ref_of(m.t)
        expect = "accept"
        if k > 0 and rng.random() < P_BAD:
            m, r, expect = corrupt(rng, m, r, last_t)
        before = ctrl.observer_state
        try:
            cmd = ctrl.step(m, r)
        except SignalError:
            assert expect == "raise", (k, m, r)
            np.testing.assert_array_equal(ctrl.observer_state, before, err_msg=f"tick {k}: raised tick changed it")
            counts["raise"] += 1
            plant.step(tau)  # the loop holds its last command
            continue
        except ReflexArmError as e:  # any other package error is a finding too: report it
            pytest.fail(f"tick {k}: unexpected {type(e).__name__}: {e}")
        except Exception as e:
            pytest.fail(f"tick {k}: foreign exception {type(e).__name__}: {e}")
        assert np.all(np.isfinite(cmd.tau)), (k, cmd)
        assert np.all(np.abs(cmd.tau) <= limit), (k, cmd.tau, limit)
        if expect == "fault":
            assert cmd.fault and cmd.mode == "fault", (k, m, r, cmd)
            np.testing.assert_array_equal(ctrl.observer_state, before, err_msg=f"tick {k}: {cmd.fault}")
        else:
            assert cmd.fault == "", (k, cmd.fault)
            last_t = float(m.t)
        assert not cmd.collision, f"tick {k}: false alarm after bad inputs: {cmd}"
        counts[expect] += 1
        tau = cmd.tau
        plant.step(tau)
    print(f"{arm} / {config}: {counts}")  # shown with pytest -s
    assert min(counts.values()) > 0.02 * TICKS, counts  # every kind of tick occurred
    # detection intact: recovery after faults is automatic (no latch happened: nothing to reset)
    assert not ctrl.observer_invalid and not ctrl.reacted
    mine, fresh = detected_as_by_a_fresh_controller(plant, ctrl, make, settle=2.0)
    assert mine is not None and mine == fresh, (mine, fresh)
