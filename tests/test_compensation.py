"""Fig. 12 (efc-step), Fig. 11 (compliance loss) and Fig. 3 (mode table) on the simulated Atlas arm.

Every run is seeded (model-error draw and sensor noise); the tolerances are the issue's targets, and
where the default plant (MuJoCo dry friction with stiction) does not meet a target the test pins down
why (see ``test_efc_step_dry_friction_explains_the_larger_ee_displacement``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from efc_statics import in_band_damping, load_torque, static_displacement, world_force
from reflexarm.control.impedance import modal_damping
from reflexarm.errors import ConfigError
from reflexarm.experiments.compensation import CompensationSetup, controller_model, held_posture, true_robot
from reflexarm.experiments.compliance_loss import PAPER_FIG11, compliance_loss, compliance_loss_sweep, real_arm_setup
from reflexarm.experiments.efc_step import efc_step
from reflexarm.experiments.metrics import msie, msie_per_joint, normalize_by_max, window_mean
from reflexarm.experiments.mode_table import mode_table
from reflexarm.experiments.plots import compliance_loss_figure, compliance_sweep_figure, efc_step_figure
from reflexarm.robots import RobotModel

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def paper():
    # the default setup: the paper's simulated arm (continuous-time Coulomb + viscous friction, Table I)
    assert CompensationSetup().plant_friction == "smooth"
    return efc_step(CompensationSetup(), seed=0)


@pytest.fixture(scope="module")
def dry():
    # the real arm's conditions (stiction, kappa_f = 0), on which the tests below were measured
    return efc_step(real_arm_setup(), seed=0)


@pytest.fixture(scope="module")
def frictionless():
    # no plant friction, so no friction compensation either (kappa_f = 1 would add a friction the arm lacks)
    return efc_step(CompensationSetup(plant_friction="none", kappa_f=0), seed=0)


def rows(result):
    return {r["run"]: r for r in result.rows}


def test_efc_step_dc_without_efc_is_stiff(dry):
    # (10): DC without EFC leaves less than half the no-DC displacement (issue's target); measured ~1 %
    r = rows(dry)
    assert dry.summary["dc_vs_nodc_displacement"] < 0.5
    assert r["no DC"]["ee_displacement_mm"] > 30.0  # the load does displace the compliant arm
    # with the observer converged, the residual carries the external torque: tau_eps_1 ~ tau_ext,1 + delta_1.
    # Tolerance 2.5 Nm: shz's static friction (mu_C = 2 Nm, any value up to it while the joint rests) is
    # part of delta_1; gravity does not act on shz (vertical axis), model errors add < 0.5 Nm.
    np.testing.assert_allclose(r["DC"]["residual1_Nm"], r["DC"]["tau_ext1_Nm"], atol=2.5)


def test_efc_step_residual_with_efc_stays_small(dry):
    # (11): with EFC the observer does not see the end-effector load. Joint 1 (the one Fig. 12 plots):
    # under 10 % of the DC-without-EFC run's residual (issue's target).
    assert dry.summary["efc_vs_dc_residual1"] < 0.10


def test_efc_step_q1_follows_the_compliant_run(dry):
    # Fig. 12 plots q_1: with EFC its displacement under the load is the no-DC run's within 5 %
    assert abs(dry.summary["efc_vs_nodc_q1"] - 1.0) < 0.05


def test_efc_step_dry_friction_explains_the_larger_ee_displacement(dry):
    # Measured: with the default plant the EE displacement with EFC is ~1.36x the no-DC run's, not within
    # 5 %. Cause: the Table I Coulomb friction of shx, ely, elx (6.7, 10.3, 6.1 Nm) exceeds the load's
    # torque on those joints (< 4 Nm), so without DC they stick (true dry friction); with DC the
    # observer sees their friction as delta and compensates it, and they yield as (11) prescribes.
    r = rows(dry)
    no_dc = np.abs(r["no DC"]["q_displacement_rad"][1:4])
    efc = np.abs(r["DC+EFC"]["q_displacement_rad"][1:4])
    assert no_dc.max() < 1e-3  # stuck (1 mrad: far below the 10-40 mrad they move with EFC)
    assert efc.max() > 0.01
    assert dry.summary["efc_vs_nodc_displacement"] > 1.05  # the target is not met on this plant: reported
    # ... and the residual of those joints is their friction, not the end-effector load: the norm
    # over all joints is not below 10 % of the DC run's (it is ~0.9), joint 1's is (previous test)
    assert dry.summary["efc_vs_dc_residual_norm"] > 0.5


def test_efc_step_meets_the_issue_targets_on_the_papers_plant(paper):
    # steady state under the 50 N load, default setup (+-10 % model errors, paper noise, smooth friction):
    # joint-1 residual below 10 % of DC-without-EFC's; DC without EFC leaves less than half the no-DC
    # displacement. The EE displacement ratio EFC / no DC is not asserted on this run: measured 0.948
    # against a static prediction of 1.000, because the runs are not at rest in the windows: joints 1 and
    # 4 oscillate (over-compensated friction), the velocity noise dithers the friction compensation, and
    # the pre-load window (0.3-0.5 s) is still in the start-up transient (see the three tests below).
    # Measured on this draw: load on at 2 s instead of 0.5 s -> 0.990; no velocity noise -> 0.993;
    # model friction = true friction and no velocity noise -> 1.000 (prediction 1.0001)
    s = paper.summary
    assert s["efc_vs_dc_residual1"] < 0.10
    assert s["dc_vs_nodc_displacement"] < 0.5


def _static_ratio(setup: CompensationSetup, model_seed: int, *, gravity_error: bool = True) -> float:
    """EE displacement EFC / no DC at rest (tests/efc_statics.py), true arm vs the run's controller model."""
    robot = true_robot(setup)
    model = controller_model(setup, model_seed=model_seed)
    q_d = held_posture(setup, robot)
    d_no, _, _ = static_displacement(robot, model if gravity_error else None, setup.stiffness, q_d, setup.force)
    d_efc, _, _ = static_displacement(robot, None, setup.stiffness, q_d, setup.force)
    return d_efc / d_no


def test_efc_step_static_ratio_under_model_error(paper):
    # The lead's hypothesis: without DC the gravity-stiffness error d(g - g_hat)/dq changes the load's
    # displacement (K - de/dq)^-1 J^T F, with DC + EFC it is K^-1 J^T F. Derived at rest from (2) on the
    # run's own model draw (tests/efc_statics.py): the ratio is 1.0001, and the gravity error moves it by
    # 1e-4 (over the load's ~0.1 rad displacement e changes by < 0.02 Nm per joint, against k = 150 Nm/rad),
    # so it cannot explain 0.948.
    setup, seed = paper.setup, paper.summary["model_seed"]
    ratio = _static_ratio(setup, seed)
    # 2e-3: the prediction is exact statics (no simulation); the model errors move the no-DC posture
    # before the load by K^-1 e ~ 1 mrad, which turns the force (resolved there) by ~1 mrad
    assert abs(ratio - 1.0) < 2e-3
    assert abs(ratio - _static_ratio(setup, seed, gravity_error=False)) < 1e-3
    # the load model of the prediction is the run's: J(q)^T F at each run's own load-window posture
    # equals the true external torque the plant recorded. 0.05 Nm: F here is resolved at the pre-window
    # mean posture, the plant resolves it at t_on (~0.5 mrad apart: 50 N x 1 m x 5e-4 = 0.025 Nm)
    robot = true_robot(setup)
    for name in ("no DC", "DC+EFC"):
        tr = paper.traces[name]
        q_on = window_mean(tr.t, tr.q, *setup.pre_window)
        q_load = window_mean(tr.t, tr.q, *setup.load_window)
        expected = load_torque(robot, q_load, world_force(robot, q_on, setup.force))
        np.testing.assert_allclose(window_mean(tr.t, tr.tau_ext, *setup.load_window), expected, atol=0.05)
    # ... while the measured ratio is 5 % off the prediction: the runs are not at rest (next test)
    assert abs(paper.summary["efc_vs_nodc_displacement"] - ratio) > 0.03


NO_VELOCITY_NOISE = ("q", "gravity", "tau_m", "force", "torque")


def test_efc_step_no_dc_displacement_matches_the_statics(monkeypatch):
    # The derivation checked on a run that does come to rest: the controller model's friction
    # coefficients set to the true ones (its in-band damping is then D_ii > 0 on every joint), no velocity
    # noise, and the load switched on at 2 s instead of 0.5 s (at 0.3-0.5 s the arm is still settling from
    # the reset: observer time constant 0.1 s, joint-1 impedance decay ~0.26 s). Model draw of seed 2, on
    # which the no-DC posture before the load sits 7 mrad (joint 2) below q_d, which turns the force and
    # makes the static ratio 1.014 rather than 1: the statics (tests/efc_statics.py) give the no-DC
    # displacement to 0.01 mm (measured 70.59 mm, predicted 70.58 mm).
    from reflexarm.experiments import compensation

    perturbed = compensation.controller_model

    def exact_friction(setup: CompensationSetup, model_error: float | None = None, model_seed: int = 0) -> RobotModel:
        return perturbed(setup, model_error, model_seed).with_friction(true_robot(setup).friction)

    monkeypatch.setattr(compensation, "controller_model", exact_friction)
    setup = dataclasses.replace(
        CompensationSetup(), noise_channels=NO_VELOCITY_NOISE, t_on=2.0, t_off=5.0, duration=5.0
    )
    res = efc_step(setup, seed=2)
    robot = true_robot(setup)
    model = exact_friction(setup, model_seed=res.summary["model_seed"])
    predicted, q0, q1 = static_displacement(robot, model, setup.stiffness, held_posture(setup, robot), setup.force)
    assert abs(_static_ratio(setup, res.summary["model_seed"]) - 1.0) > 0.01  # the posture offset matters here
    measured = rows(res)["no DC"]["ee_displacement_mm"]
    # 0.2 mm: the remaining sensor noise (q and gravity enter the no-DC torque) moves the window means by
    # < 0.1 mrad per joint
    # (measured 0.05), < 0.1 mm at the < 1 m lever
    assert measured == pytest.approx(1000 * predicted, abs=0.2)
    tr = res.traces["no DC"]
    np.testing.assert_allclose(window_mean(tr.t, tr.q, *setup.pre_window), q0, atol=2e-4)
    np.testing.assert_allclose(window_mean(tr.t, tr.q, *setup.load_window), q1, atol=2e-4)


def test_efc_step_overcompensated_friction_keeps_joints_moving(paper):
    # What explains 0.948. With kappa_f = 1 the controller compensates its model's friction
    # mu_C_hat clip(dq / band) + d_v_hat dq; inside the band (0.02 rad/s) the plant's smooth friction has
    # the slope mu_C / band = 100-500 Nms/rad, so a model that overestimates mu_C by a few % leaves a
    # negative in-band damping (mu_C - mu_C_hat) / band larger than the impedance damping D_ii of (2)
    # (0.2-7 Nms/rad): that joint cannot come to rest. On this run's model draw: joints 1 and 4
    # (1-based; -1.3 and -15.6 Nms/rad).
    setup, seed = paper.setup, paper.summary["model_seed"]
    robot = true_robot(setup)
    model = controller_model(setup, model_seed=seed)
    q_d = held_posture(setup, robot)
    n = robot.n
    D = modal_damping(model.compute_mass_matrix(q_d), np.full(n, setup.stiffness), np.full(n, setup.damping_ratio))
    net = in_band_damping(robot, model, np.diag(D))
    assert sorted(int(j) + 1 for j in np.flatnonzero(net < 0)) == [1, 4]
    # the same draw without velocity noise (the band is then resolved by the measured dq): in the no-DC
    # run those two joints keep moving over the load window, peak-to-peak > 3 mrad (measured 5.0 and
    # 12 mrad), while with the exact model (net in-band damping = D_ii > 0) no joint moves by 1 mrad
    quiet = dataclasses.replace(setup, noise_channels=NO_VELOCITY_NOISE)
    exact = dataclasses.replace(quiet, model_error=0.0)
    spans = {}
    for key, s in (("draw", quiet), ("exact", exact)):
        tr = efc_step(s, seed=0).traces["no DC"]
        m = (tr.t >= s.load_window[0]) & (tr.t < s.load_window[1])
        spans[key] = tr.q[m].max(axis=0) - tr.q[m].min(axis=0)
    assert spans["draw"][[0, 3]].min() > 3e-3
    assert spans["exact"].max() < 1e-3


def test_efc_step_without_model_error_meets_the_target(paper):
    # the exact model (static ratio 1 exactly: e = 0 and the same force at the same posture) and no
    # velocity noise: every joint rests, and the measured ratio is 1 to 1 % (measured 1.0000; over noise
    # seeds 0-2: 1.0000, 1.0050, 0.9982: in the DC+EFC run the observer output is fed back, and its noise
    # below k_o = 10 1/s (tau_m and wrench channels) moves the joints by ~0.5 mrad over a 0.5 s window).
    # With the paper's velocity noise (sigma_dq ~ 0.28 rad/s, 14x the band) the friction compensation
    # becomes a random +-mu_C_hat torque (the 7e-4 kg m^2 wrist roll chatters at ~2 rad/s RMS): the issue's 5 %
    # then holds for seed 0 (measured 0.9963) but is not a derived bound (seed 1: 1.031)
    exact = dataclasses.replace(paper.setup, model_error=0.0)
    assert _static_ratio(exact, 0) == pytest.approx(1.0, abs=1e-12)
    quiet = efc_step(dataclasses.replace(exact, noise_channels=NO_VELOCITY_NOISE), seed=0)
    assert abs(quiet.summary["efc_vs_nodc_displacement"] - 1.0) < 0.01
    noisy = efc_step(exact, seed=0)
    assert abs(noisy.summary["efc_vs_nodc_displacement"] - 1.0) < 0.05


def test_efc_step_meets_the_paper_on_a_plant_without_stiction(frictionless):
    # the same experiment on a frictionless arm: EE displacement with EFC within 5 % of no-DC, the
    # residual (every joint, norm) below 10 % of DC-without-EFC, DC under half the no-DC displacement
    s = frictionless.summary
    assert abs(s["efc_vs_nodc_displacement"] - 1.0) < 0.05
    assert s["efc_vs_dc_residual_norm"] < 0.10
    assert s["dc_vs_nodc_displacement"] < 0.5


def test_efc_step_cutoff_not_reached_by_the_50N_load(dry):
    # the 50 N step produces < 30 Nm on every joint: the cut-off never acts, so it explains none of
    # the DC run's (already tiny) displacement; the runs with and without it are identical
    r = rows(dry)
    assert dry.summary["peak_dc_residual_Nm"] < 30.0
    assert dry.summary["cutoff_share_of_dc_displacement"] == 0.0
    np.testing.assert_array_equal(dry.traces["DC"].q, dry.traces["DC, no cut-off"].q)
    assert r["DC"]["ee_displacement_mm"] < 2.0


def test_efc_step_release_returns_with_dc(dry):
    # after the release the DC runs return to q_d (model errors compensated), the compliant one keeps
    # a friction dead-band offset (stiction holds it)
    r = rows(dry)
    assert r["DC+EFC"]["ee_after_release_mm"] < 0.5 * r["no DC"]["ee_after_release_mm"]


def test_efc_step_figure_shows_the_three_runs(dry):
    # Fig. 12's three panels (q_1, tau_ext,1, residual_1: joint 1 carries the load on Atlas), each with one
    # line per run, drawn from the traces
    fig = efc_step_figure(dry)
    assert dry.joint == 0
    assert [ax.get_ylabel() for ax in fig.axes] == [
        "$q_{1}$ [rad] (loaded joint)",
        "$\\tau_{ext,1}$ [Nm]",
        "$\\hat{\\tau}_{\\varepsilon,1}$ [Nm]",
    ]
    for ax, column in zip(fig.axes, ("q", "tau_ext", "residual"), strict=True):
        lines = ax.get_lines()
        assert [ln.get_label() for ln in lines] == [
            "DC off ($\\kappa_\\varepsilon=0$)",
            "DC, no EFC ($\\kappa_{ext}=0$)",
            "DC + EFC ($\\kappa_{ext}=1$)",
        ]
        for ln, run in zip(lines, ("no DC", "DC", "DC+EFC"), strict=True):
            np.testing.assert_array_equal(ln.get_ydata(), getattr(dry.traces[run], column)[:, 0])
    assert fig.axes[-1].get_xlabel() == "t [s]"


@pytest.fixture(scope="module")
def push():
    return compliance_loss(seed=0)


def test_compliance_loss_dc_stiffens_and_the_cutoff_limits_it(push):
    s = push.summary
    by = rows(push)
    # Fig. 11: with DC the hand needs more force for less displacement (paper: force x1.93, position
    # x0.67, stiffness x2.87); measured here x1.77, x0.42, x4.2 with a 2000 N/m hand.
    assert s["force_ratio"] > 1.3
    assert s["displacement_ratio"] < 0.8
    assert s["stiffness_ratio"] > 2.0
    # the 30 Nm cut-off acts (the raw residual passes it) and is what keeps the stiffening finite:
    # without it the arm would hold its position (stiffness ratio > 10x the cut-off's; measured ~1700x)
    assert by["DC"]["residual1_Nm"] > 30.0
    assert s["stiffness_ratio_no_cutoff"] > 10 * s["stiffness_ratio"]
    assert by["DC, no cut-off"]["displacement_mm"] < 5.0


def test_compliance_loss_figure_shows_force_and_displacement(push):
    fig = compliance_loss_figure(push)
    ax_x, ax_f, ax_r = fig.axes
    assert ax_x.get_ylabel().startswith("$\\Delta x$") and ax_f.get_ylabel() == "$|f|$ [N]"
    for ax in fig.axes:
        assert [ln.get_label() for ln in ax.get_lines()][:3] == ["no DC", "DC", "DC, no cut-off"]
    # the force panel is the hand's force of each run
    for ln, run in zip(ax_f.get_lines(), ("no DC", "DC", "DC, no cut-off"), strict=True):
        np.testing.assert_allclose(ln.get_ydata(), np.linalg.norm(push.traces[run].extras["hand_force"], axis=1))
    # the cut-off drawn at +-30 Nm on the residual panel
    assert sorted(ln.get_ydata()[0] for ln in ax_r.get_lines()[3:]) == [-30.0, 30.0]


def test_compliance_loss_over_the_hand_stiffness_brackets_the_paper():
    # Fig. 11 gives no hand stiffness. A soft hand (500 N/m, 10 cm) loads joint 1 below the 30 Nm cut-off:
    # DC cancels the push as (10) says, the arm holds its position (measured: displacement x0.01,
    # stiffness x123). A firm hand (5000 N/m) drives the residual past the cut-off: beyond it the arm
    # yields with its impedance, and the ratios come near the paper's (measured force x1.86, displacement
    # x0.79, stiffness x2.36; paper 1.93, 0.67, 2.88). Bounds: the paper's values with the measured ones
    # inside, decided by whether the cut-off binds.
    sweep = compliance_loss_sweep([500.0, 5000.0], seed=0)
    soft, firm = sweep.rows()
    assert soft["peak_dc_residual_Nm"] < 30.0
    assert soft["displacement_ratio"] < 0.05 and soft["stiffness_ratio"] > 20
    assert firm["peak_dc_residual_Nm"] > 30.0
    assert 1.5 < firm["force_ratio"] < 2.2 and 0.5 < firm["displacement_ratio"] < 1.0
    assert 1.5 < firm["stiffness_ratio"] < 4.0
    assert firm["paper_force_ratio"] == PAPER_FIG11["force_ratio"] == 1.93
    fig = compliance_sweep_figure(sweep)
    ax = fig.axes[0]
    lines = {ln.get_label(): ln.get_ydata() for ln in ax.get_lines()}
    np.testing.assert_allclose(lines["force (ours)"], [soft["force_ratio"], firm["force_ratio"]])
    assert lines["displacement (paper 0.67)"][0] == pytest.approx(0.67)
    assert ax.get_xscale() == "log" and ax.get_xlabel() == "hand stiffness [N/m]"
    with pytest.raises(ConfigError, match="hand stiffness must be positive and finite \\[N/m\\]; got -1.0"):
        compliance_loss_sweep([-1.0])


def test_mode_table_agrees_with_every_check_mark_of_fig3():
    table, traces = mode_table(seed=0)
    by = {r["mode"]: r for r in table}
    assert all(r["agrees_with_paper"] for r in table), table
    # the numbers behind the marks, with margins from the 0.5 decision line
    assert by["precise_stiff"]["accuracy_ratio"] < 0.3 and by["precise_ee_compliant"]["accuracy_ratio"] < 0.3
    assert by["compliant"]["ee_compliance_ratio"] > 0.8 and by["precise_ee_compliant"]["ee_compliance_ratio"] > 0.8
    assert by["precise_stiff"]["ee_compliance_ratio"] < 0.1
    assert by["compliant"]["link_compliance_ratio"] > 0.8
    assert by["precise_stiff"]["link_compliance_ratio"] < 0.1
    assert by["precise_ee_compliant"]["link_compliance_ratio"] < 0.1
    # the supervisor's automatic switch gives every mode its link compliance back, and it is logged
    assert all(r["link_compliant_supervised"] for r in table)
    log = traces["precise_ee_compliant/link_force/supervised"].meta["mode_transitions"]
    assert [(x["from"], x["to"], x["cause"]) for x in log] == [
        ("", "precise_ee_compliant", "task"),
        ("precise_ee_compliant", "compliant", "collision"),
    ]
    tr = traces["precise_ee_compliant/link_force/supervised"]
    assert tr.mode[0] == "precise_ee_compliant" and tr.mode[-1] == "compliant"


def test_setup_validation():
    with pytest.raises(ConfigError, match="unknown plant friction 'wet'; choose one of: dry, smooth, none"):
        CompensationSetup(plant_friction="wet")
    with pytest.raises(ConfigError, match="model_error must be non-negative; got -0.1"):
        CompensationSetup(model_error=-0.1)
    with pytest.raises(ConfigError, match="need 0 <= t_on < t_off"):
        CompensationSetup(t_on=2.0, t_off=1.0)


def test_msie_matches_its_definition():
    # eq. (20) against a hand computation: q - q_ref = a sin(w t) on one joint, 0 on the other, over a
    # whole number of periods: (1/(n T)) int a^2 sin^2 = a^2 / (2 n)
    t = np.linspace(0.0, 2.0, 20001)
    a = 0.1
    q = np.zeros((t.size, 2))
    q[:, 0] = a * np.sin(2 * np.pi * t)
    assert msie(t, q, np.zeros_like(q)) == pytest.approx(a**2 / 4, rel=1e-6)
    np.testing.assert_allclose(msie_per_joint(t, q, np.zeros_like(q)), [a**2 / 2, 0.0], atol=1e-9)
    np.testing.assert_allclose(normalize_by_max([1.0, 4.0, 2.0]), [0.25, 1.0, 0.5])
    assert window_mean(t, q[:, 1], 0.0, 1.0) == 0.0


def test_an_identified_model_file_is_the_controllers_model(atlas, tmp_path):
    # --model FILE: the file's parameters (here those of a perturbed model written as an identification
    # result) become the controller's model, exactly; a level on top of it is refused
    from reflexarm.experiments.compensation import controller_model
    from reflexarm.ident import compute_base_parameters, save_identified_model
    from reflexarm.ident.estimation.identify import DynamicsIdentification, FrictionParameters
    from reflexarm.robots import perturb_model

    pert = perturb_model(atlas, 0.2, seed=5)
    base = compute_base_parameters(atlas)
    pi = pert.inertial_parameters()
    n = atlas.n
    res = DynamicsIdentification(
        method="sequential",
        robot_name=atlas.name,
        joint_names=tuple(atlas.joint_names),
        base=base,
        beta_b=base.base_from_standard(pi),
        friction=FrictionParameters.from_model(pert.friction),
        beta_std=np.zeros(base.n_base),
        noise_variance=np.ones(n),
        condition_number=1.0,
        n_samples=1,
        residual_rms=np.zeros(n),
        physical_parameters=pi,
    )
    path = save_identified_model(res, atlas, tmp_path / "model.json")
    setup = CompensationSetup(model_file=str(path))
    model = controller_model(setup)
    q = np.random.default_rng(0).uniform(atlas.lower_limit, atlas.upper_limit)
    # tolerance: the file stores the parameters as JSON decimal text (17 significant digits round-trip)
    np.testing.assert_allclose(model.compute_gravity(q), pert.compute_gravity(q), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(model.compute_mass_matrix(q), pert.compute_mass_matrix(q), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(model.friction.coulomb, pert.friction.coulomb, rtol=1e-12)
    assert np.abs(model.compute_gravity(q) - atlas.compute_gravity(q)).max() > 0.1  # not the true model
    with pytest.raises(ConfigError, match="the setup uses the identified model .* got model_error 0.1 as well"):
        controller_model(setup, 0.1)
