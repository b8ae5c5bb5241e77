"""experiments.detection_study: a short pulse is caught by the fast detection observer and missed by the slow
one; the contact lag counts from the true crossing; a tiny study runs end to end and writes its files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reflexarm.control import Controller
from reflexarm.errors import ConfigError
from reflexarm.experiments.collision import EE_START, CollisionSetting
from reflexarm.experiments.detection_study import (
    PULSE_GRACE_S,
    contact_lag,
    free_motion_residuals,
    input_lag,
    lag_spread,
    observer_input,
    run_detection_study,
    study_arm_detection,
)
from reflexarm.experiments.reaction_study import study_arm
from reflexarm.signals import Measurement, Reference
from reflexarm.tuning import refilter

DT = 1e-3


def _first_detection(atlas, gain: float, zeta: float, ext: np.ndarray) -> int | None:
    """First tick the Controller (exact form, detection observer at ``gain``) flags, the arm held still with the
    external torque ``ext`` (N, n)."""
    ctrl = Controller(atlas, detection_observer_gain=gain, observer_discretization="exact", threshold=zeta,
                      reaction="none", torque_limit=None)  # fmt: skip
    g, zeros = atlas.compute_gravity(EE_START), np.zeros(atlas.n)
    gravity = np.asarray(atlas.gravity, dtype=float)
    for k in range(ext.shape[0]):
        cmd = ctrl.step(Measurement(k * DT, EE_START, zeros, g - ext[k], np.zeros(6), gravity),
                        Reference(EE_START, zeros, zeros))  # fmt: skip
        if cmd.collision:
            return k
    return None


@pytest.mark.parametrize("width_s", [0.010, 0.020, 0.030])
def test_a_short_pulse_is_caught_by_the_fast_observer_only(atlas, width_s):
    """A pulse of 3 zeta for 10-30 ms on joint 2: the 200 1/s observer crosses zeta during it (T = 5 ms: it
    reaches 3 (1 - e^{-2}) zeta = 2.6 zeta by 10 ms); the paper's 5 1/s reaches 3 (1 - e^{-0.15}) = 0.42 zeta at
    most and never detects."""
    zeta, k0 = 10.0, 200
    ext = np.zeros((600, atlas.n))
    ext[k0 : k0 + int(round(width_s / DT)), 1] = 3.0 * zeta
    fast = _first_detection(atlas, 200.0, zeta, ext)
    assert fast is not None and k0 <= fast <= k0 + int(round((width_s + PULSE_GRACE_S) / DT))
    assert _first_detection(atlas, 5.0, zeta, ext) is None


class _Trace:
    """The fields contact_lag reads."""

    def __init__(self, tau_ext: np.ndarray, collision: np.ndarray, collided: np.ndarray) -> None:
        self.t = np.arange(tau_ext.shape[0]) * DT
        self.tau_ext, self.collision, self.collided = tau_ext, collision, collided


def test_contact_lag_counts_from_the_first_true_crossing():
    n, N = 3, 100
    tau = np.zeros((N, n))
    tau[:, 1] = np.linspace(0.0, 20.0, N)  # crosses 10 Nm at tick 50
    tau[:, 2] = np.linspace(0.0, 30.0, N)  # crosses 10 Nm at tick 34
    collision = np.arange(N) >= 60
    collided = np.zeros((N, n), dtype=bool)
    collided[60:, 1] = True
    row = contact_lag(_Trace(tau, collision, collided), np.full(n, 10.0))  # type: ignore[arg-type]
    first2 = int(np.argmax(tau[:, 2] > 10.0))
    first1 = int(np.argmax(tau[:, 1] > 10.0))
    assert row["lag_s"] == pytest.approx((60 - first2) * DT)  # from the earliest crossing on any joint
    assert row["lag_detecting_joint_s"] == pytest.approx((60 - first1) * DT)  # on the joint that crossed
    assert row["detecting_joints"] == [2]
    none = contact_lag(_Trace(tau, np.zeros(N, dtype=bool), collided), np.full(n, 10.0))  # type: ignore[arg-type]
    assert none["lag_s"] is None and none["detected_s"] is None
    # detected at tick 20, before any true crossing: a crossing after detection (the reaction's run) does not count
    early = contact_lag(_Trace(tau, np.arange(N) >= 20, collided), np.full(n, 10.0))  # type: ignore[arg-type]
    assert early["detected_s"] == pytest.approx(20 * DT) and early["true_crossing_s"] is None
    assert early["lag_s"] is None and early["lag_detecting_joint_s"] is None
    assert lag_spread([early])["detected_without_crossing"] == 1


class _Log:
    """The fields observer_input reads (a run's true states and measured torque)."""

    def __init__(self, t, q, dq, tau_m) -> None:
        self.t, self.q, self.dq, self.tau_m = t, q, dq, tau_m
        self.wrench = np.zeros((t.size, 6))


#: |LP_k(observer_input) - the residual at k| / max |residual|: the input replay is the observer at k_o dt = 10,
#: whose own lag leaves e^-10 = 4.5e-5 of the previous tick in each sample; 1e-3 leaves 20x room for it.
INPUT_FILTER_TOL = 1e-3


def test_the_observer_input_filtered_at_the_gain_is_the_residual(atlas):
    """observer_input is the detecting observer's input with its filter taken out: a first-order filter at k_o
    (zero-order hold, written here) of it gives the residual of a replay at k_o, on a moving arm whose torque
    is gravity plus a growing external torque (the model's error torques, here its C^T dq and friction)."""
    N, k = 1500, 50.0
    t = (np.arange(N) + 1) * DT
    w = 2.0 * np.pi * 0.5
    q = EE_START + 0.3 * np.sin(w * t)[:, None]
    dq = 0.3 * w * np.cos(w * t)[:, None] * np.ones(atlas.n)
    tau_m = np.array([atlas.compute_gravity(x) for x in q])
    tau_m[:, 1] += np.clip(40.0 * (t - 0.8), 0.0, None)  # a contact torque ramping from 0.8 s
    log = _Log(t, q, dq, tau_m)
    setting = CollisionSetting("probe", stiffness=300.0, threshold=None, reaction="none",
                               detection_observer_gain=k, observer_discretization="exact")  # fmt: skip
    d = observer_input(log, setting, atlas)  # type: ignore[arg-type]
    from reflexarm.control import replay

    ref = replay(setting.controller(atlas), t, q, dq, tau_m).residual
    a, lp, y = np.exp(-k * DT), np.empty_like(d), np.zeros(atlas.n)
    for i in range(N):
        y = a * y + (1.0 - a) * d[i]
        lp[i] = y
    assert np.abs(lp - ref).max() <= INPUT_FILTER_TOL * np.abs(ref).max()
    assert np.abs(d[1200:, 1]).max() > 1.5 * np.abs(ref[1200:, 1] - d[1200:, 1]).max()  # the input leads


def test_input_lag_counts_from_the_input_crossing_after_contact():
    n, N = 3, 100
    tau = np.zeros((N, n))
    disturbance = np.zeros((N, n))
    disturbance[5, 0] = 50.0  # a crossing before contact: not the contact's
    disturbance[:, 1] = np.linspace(0.0, 20.0, N)  # crosses 10 Nm at tick 50
    collision = np.arange(N) >= 57
    collided = np.zeros((N, n), dtype=bool)
    collided[57:, 1] = True
    row = input_lag(_Trace(tau, collision, collided), np.full(n, 10.0), disturbance, contact_s=20 * DT)  # type: ignore[arg-type]
    first = int(np.argmax(disturbance[:, 1] > 10.0))
    assert row["input_lag_s"] == pytest.approx((57 - first) * DT)
    assert row["input_lag_detecting_joint_s"] == pytest.approx((57 - first) * DT)
    none = input_lag(_Trace(tau, collision, collided), np.full(n, 10.0), disturbance, contact_s=None)  # type: ignore[arg-type]
    assert none["input_lag_s"] is None


def test_chunked_free_motion_residuals_refilter_per_chunk():
    arm = study_arm("iiwa14_frictionless")
    reps = free_motion_residuals(arm, 1.0, gain=200.0, model_seed=1, seed=1, chunk_s=0.5)
    assert len(reps) == 2 and all(r.detection_gain == 200.0 and r.discretization == "exact" for r in reps)
    slow = [refilter(r, 20.0) for r in reps]
    # the velocity noise passed by the observer grows with its gain
    assert np.std(reps[0].residual[100:], axis=0).sum() > 3.0 * np.std(slow[0].residual[100:], axis=0).sum()


def test_a_tiny_study_runs_and_writes_its_files(tmp_path):
    study = run_detection_study(["iiwa14_frictionless"], (50.0, 200.0), tune_s=40.0, tune_models=2, heldout_s=10.0,
                                pulses=3, rate_per_hour=30.0, chunk_s=20.0, contact_seeds=1)  # fmt: skip
    arm = study.arms["iiwa14_frictionless"]
    assert [p["detection_observer_gain"] for p in arm["pairs"]["pairs"]] == [50.0, 200.0]
    assert set(arm["contacts"]["200.0"]) == {"demo", "link"}
    assert set(arm["pulses"]["caught"]) == {"50.0", "200.0"} and len(arm["pulses"]["specs"]) == 3
    files = study.write(tmp_path)
    assert all(p.is_file() for p in files.values())
    doc = json.loads(files["json"].read_text())
    assert doc["arms"]["iiwa14_frictionless"]["plant_friction"] == "none"
    assert len(study.rows()) == 2


def test_a_seeded_free_motion_is_another_log_of_the_same_motion():
    """Tuning and held-out logs of one arm differ in motion: a seed reorders and moves the waypoints (within the
    joint ranges) and rescales the segments; no seed gives the fixed cycle, one seed always the same motion."""
    from reflexarm.experiments.collision import free_motion_trajectory
    from reflexarm.experiments.free_motion_variation import FREE_MOTION_JITTER_RAD

    robot = study_arm("panda").robot
    t = np.arange(0.0, 60.0, 0.05)

    def path(seed):
        traj = free_motion_trajectory(60.0, "loaded", robot, seed=seed)
        return np.array([traj.sample(s).q_d for s in t])

    fixed, a, a2, b = path(None), path(1), path(1), path(2)
    np.testing.assert_array_equal(a, a2)
    assert np.abs(a - b).max() > 0.1 and np.abs(a - fixed).max() > 0.1
    assert np.all(a >= robot.lower_limit - 1e-12) and np.all(a <= robot.upper_limit + 1e-12)
    # the same region: every posture of the seeded log lies within the fixed cycle's box widened by the jitter
    lo, hi = fixed.min(axis=0) - FREE_MOTION_JITTER_RAD - 1e-9, fixed.max(axis=0) + FREE_MOTION_JITTER_RAD + 1e-9
    assert np.all((a >= lo) & (a <= hi))


def test_the_printed_table_has_the_detecting_joint_s_lag_beside_the_any_joint_lag(capsys):
    # Atlas' demo at 100 1/s: the first true crossing was a 1 ms spike on another joint than the detecting one, so
    # the lag from any joint (122 ms) and on the detecting joint (10 ms) differ; both are printed
    from reflexarm._cli.detection import _print

    pair = {"detection_observer_gain": 100.0, "collision_Nm": [23.8, 0.28], "ramp_lag_max_s": 0.0096,
            "measured_ramp_lag_max_s": 0.0228, "heldout": {"alarms_per_hour": 0.0}}  # fmt: skip
    demo = {"lag_s": 0.122, "lag_detecting_joint_s": 0.010, "input_lag_s": 0.010, "delay_s": 0.126}
    arm = {"plant_friction": "file", "pairs": {"pairs": [pair]}, "contacts": {"100.0": {"demo": demo, "link": {}}}}
    _print("atlas_v5_left_arm", arm)
    header, row = capsys.readouterr().out.strip().splitlines()[-2:]
    assert header.split()[6:10] == ["demo", "lag", "joint", "own"]
    assert row.split()[5:9] == ["122.0", "10.0", "10.0", "126.0"]


def test_the_lag_spread_over_noise_seeds_counts_each_kind_of_run():
    runs = [
        {"detected_s": 1.0, "lag_detecting_joint_s": 0.004, "delay_s": 0.012},
        {"detected_s": 1.0, "lag_detecting_joint_s": 0.010, "delay_s": 0.020},  # at the target: within it
        {"detected_s": 1.0, "lag_detecting_joint_s": 0.056, "delay_s": 0.300},
        {"detected_s": 1.0, "lag_detecting_joint_s": None, "delay_s": 0.100},  # the detecting joints never over
        {"detected_s": None, "delay_s": None},  # not detected
    ]
    s = lag_spread(runs)
    assert s["delays_s"][-1] is None and s["delay_median_s"] == pytest.approx(0.060)  # of the 4 detected runs
    assert s["delay_max_s"] == pytest.approx(0.300)
    assert s["lags_s"] == [0.004, 0.010, 0.056, None, None] and s["seeds"] == 5
    assert s["median_s"] == pytest.approx(0.010) and s["max_s"] == pytest.approx(0.056)
    assert (s["within_target"], s["detected_without_crossing"], s["undetected"]) == (2, 1, 1)
    assert lag_spread([{"detected_s": None}])["median_s"] is None


def test_a_study_runs_its_contacts_over_the_noise_seeds_and_refuses_none(tmp_path):
    study = run_detection_study(["iiwa14_frictionless"], (200.0,), tune_s=20.0, tune_models=1, heldout_s=10.0,
                                pulses=0, rate_per_hour=30.0, chunk_s=20.0, contact_seeds=2)  # fmt: skip
    arm = study.arms["iiwa14_frictionless"]
    spread = arm["contact_seeds"]["200.0"]
    assert set(spread) == {"demo", "link"} and spread["demo"]["seeds"] == 2
    # the first seed's run is the one in "contacts"
    assert spread["demo"]["lags_s"][0] == arm["contacts"]["200.0"]["demo"].get("lag_detecting_joint_s")
    (row,) = study.rows()
    assert row["demo_seeds"] == 2 and row["demo_within_target"] == spread["demo"]["within_target"]
    for bad in (0, 1.5, True):
        with pytest.raises(ConfigError, match="contact_seeds must be an integer >= 1"):
            study_arm_detection(study_arm("iiwa14_frictionless"), (200.0,), contact_seeds=bad)


def test_the_figure_draws_the_delays_over_the_seeds_beside_the_lags(tmp_path):
    from matplotlib.image import imread

    from reflexarm.experiments.detection_plots import plot_tradeoff
    from reflexarm.experiments.detection_study import DetectionStudy

    def spread(lag: float, delay: float) -> dict:
        return lag_spread([{"detected_s": 1.0, "lag_detecting_joint_s": lag, "delay_s": delay}] * 3)

    pairs = [{"detection_observer_gain": k, "collision_Nm": [5.0], "ramp_lag_max_s": 1.0 / k,
              "measured_ramp_lag_max_s": 1.2 / k, "measured_step_lag_median_s": None, "measured_step_lag_max_s": None,
              "measured_ramp_lag_median_s": None, "step_lag_s": None, "heldout": {"alarms_per_hour": 0.0}}
             for k in (5.0, 100.0)]  # fmt: skip
    demo = {"lag_s": 0.02, "input_lag_s": 0.01, "delay_s": 0.02}
    arm = {"pairs": {"pairs": pairs}, "contacts": {"5.0": {"demo": demo}, "100.0": {"demo": demo}},
           "contact_seeds": {"5.0": {"demo": spread(0.02, 0.02)}, "100.0": {"demo": spread(0.008, 0.15)}}}  # fmt: skip
    study = DetectionStudy(arms={"panda": arm})
    row = next(r for r in study.rows() if r["gain_per_s"] == 100.0)
    assert (row["demo_delay_median_s"], row["demo_joint_lag_max_s"]) == (0.15, 0.008)
    path = plot_tradeoff(study, tmp_path / "f.png")
    assert imread(path).shape[1] > 1.4 * imread(plot_tradeoff(DetectionStudy(arms={"panda": {**arm,
        "contact_seeds": {}}}), tmp_path / "g.png")).shape[1]  # a third panel: the delays  # fmt: skip
