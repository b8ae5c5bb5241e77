"""Issue 9 "what it must show": the whole workflow on four arms, from the command line, chained as a user
chains it. Panda (built-in), the UR-like 6-DoF arm the project writes (package:// meshes, ros2_control and
gazebo tags, a gripper cut off with ``--tip tool0``), the Menagerie iiwa14 (MJCF) and Atlas cut from the
whole-robot ``atlas_v5.urdf`` with ``--base utorso --tip l_hand``.

Per arm: ``excite`` (an optimized excitation, run on the simulated plant: the log a robot records, and the
sampled trajectory) -> ``identify friction`` -> ``identify dynamics`` on that log (model file and robot
copy) -> ``validate`` on a held-out log -> ``simulate free-motion`` with the identified model (a free-motion
log) -> ``tune-thresholds`` on it -> ``demo`` and ``simulate link-collision`` with ``--model`` the
identified model; ``efc-step`` (disturbance compensation) with the default +-10 % model (see there).

The commands run in-process through :func:`reflexarm.cli.main` rather than in subprocesses: the same
argument parsing and command code, without ~3 s of imports for each of the 10 commands per arm on a shared
2-core machine, and a failing step's traceback in the test report (the installed ``reflexarm`` script
is this ``main``: pyproject's [project.scripts]). Settings are short (10 s excitations, 3 harmonics, 2
friction speeds per joint, 14 cycles of free motion; ~45-60 s of CPU per arm); the assertions are about what
each step must deliver, not the precision a long run would give.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from conftest import SHARED
from reflexarm.cli import main
from reflexarm.errors import ReflexArmError
from reflexarm.experiments.collision import free_motion_trajectory
from reflexarm.experiments.collision_summary import CONTACT_FORCE_N
from reflexarm.ident import load_identified_model
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.logs.files import load_log
from reflexarm.robots import load_robot
from reflexarm.robots.example_arms import UR_LIKE_TIP, write_ur_like_arm

IIWA = SHARED / "reference" / "menagerie" / "iiwa14.xml"
ATLAS_V5 = SHARED / "reference" / "atlas" / "atlas_v5.urdf"
ARMS = ("panda", "ur_like", "iiwa14", "atlas_cut")

#: The excitation's period at the default base frequency 0.1 Hz [s]; one period is recorded.
PERIOD_S = 10.0
#: Free-motion log for tune-thresholds, in cycles of the demo's swing (out and back, 13-16.6 s on these
#: arms): the tail fit needs 20 separate excursions of each joint's residual (1 s apart). With an identified
#: model the residual is dominated by its deterministic model error, which repeats with the motion, so the
#: excursions come with the cycles (measured: about 2 per cycle; 9.1 cycles gave 18-19 on the UR-like arm,
#: refused; 11.5 cycles were enough on Panda), not with the log's length over the gap. 14 cycles: >= 24.
FREE_MOTION_CYCLES = 14
#: Friction runs: two speeds per joint [rad/s] (a line through Coulomb + viscous needs two).
FRICTION_SPEEDS = (0.2, 0.5)
#: Friction torque at the run speeds against the plant's: 0.02 Nm, a quarter of the paper's torque noise
#: (0.073 Nm per sample), which the fit averages over each constant-velocity segment, and below the Atlas
#: file's viscous friction (0.02-0.05 Nm at these speeds: a fit of 0 fails); plus 2 % for the rigid-body
#: torque removed with the +-10 % model errors of the runs' controller (measured: 0.002-0.015 Nm, 1.3 %).
FRICTION_ATOL_NM = 0.02
FRICTION_RTOL = 0.02
#: The identified model's held-out RMSE against the floor the robot file's exact parameters reach on the
#: same log (sensor noise, 10 Hz filtering, Coulomb friction at velocity reversals): within 5 %
#: (measured 0.996-1.015 on the four arms; the +-10 % model of the experiments: 1.03-1.16).
FLOOR_FACTOR = 1.05


class KnownFinding(AssertionError):
    """A step that fails for a finding in /work/briefs/s12/H_findings.md (the other steps still run)."""


#: (arm, step) pairs that fail today, with the finding: the arm's test is xfail(strict) for exactly this
#: error (raises=KnownFinding); any other failure fails it, and a fixed step makes it XPASS (strict: fails).
#: (atlas_cut, demo) is fixed (issue 18 item 10): atlas_v5.urdf's l_hand has an inertial and no geometry at
#: all, so nothing beyond the wrist sensor could touch the block; links with a mass and no collision geometry
#: now get a stand-in box in the plant, as links whose meshes are missing do (robots/_urdf.py).
KNOWN_FINDINGS: dict[tuple[str, str], str] = {}


def arm_param(arm: str) -> Any:
    """The arm as a test parameter, xfail(strict) for its known finding if it has one."""
    reasons = [reason for (known_arm, _), reason in KNOWN_FINDINGS.items() if known_arm == arm]
    if not reasons:
        return arm
    return pytest.param(arm, marks=pytest.mark.xfail(strict=True, raises=KnownFinding, reason="; ".join(reasons)))


class Steps:
    """Runs the checks of one arm; a check failing for a known finding is kept and raised at the end."""

    def __init__(self, arm: str) -> None:
        self.arm = arm
        self.known: list[str] = []

    def check(self, step: str, check: Any, *args: Any) -> Any:
        reason = KNOWN_FINDINGS.get((self.arm, step))
        if reason is None:
            return check(*args)
        try:
            return check(*args)
        except (AssertionError, ReflexArmError) as e:
            self.known.append(f"{step}: {reason} ({type(e).__name__}: {str(e)[:300]})")
            return None

    def finish(self) -> None:
        if self.known:
            raise KnownFinding("; ".join(self.known))


def robot_options(arm: str, folder: Path) -> list[str]:
    """The arm's robot options, as a user types them."""
    if arm == "panda":
        return ["--robot", "panda"]
    if arm == "ur_like":
        return ["--robot", str(write_ur_like_arm(folder)), "--tip", UR_LIKE_TIP]
    if arm == "iiwa14":
        if not IIWA.is_file():
            pytest.skip(f"{IIWA} is absent")
        return ["--robot", str(IIWA), "--ee-frame", "attachment_site"]
    if not ATLAS_V5.is_file():
        pytest.skip(f"{ATLAS_V5} is absent")
    return ["--robot", str(ATLAS_V5), "--base", "utorso", "--tip", "l_hand"]


def load_from_options(options: list[str], source: str | None = None, ee_frame: str | None = None) -> Any:
    """The RobotModel the options load (``source`` replaces the robot file, e.g. by a written copy)."""
    flags = dict(zip(options[::2], options[1::2], strict=True))
    named = (("ee_frame", "--ee-frame"), ("base", "--base"), ("tip", "--tip"))
    kwargs: dict[str, Any] = {key: flags[flag] for key, flag in named if flag in flags}
    if ee_frame is not None:
        kwargs["ee_frame"] = ee_frame
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the files' notes (meshes, stand-in boxes, locked joints) are tested elsewhere
        return load_robot(source or flags["--robot"], **kwargs)


def run(argv: list[str]) -> None:
    """One command, as typed; exit code 0 or the test fails naming it."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # warnings the commands give on these arms are tested where they are made
        code = main(argv)
    assert code == 0, f"reflexarm {' '.join(argv)} exited with {code}"


def check_excitation(out: Path, robot: Any) -> None:
    """excite: the coefficients reload, the optimizer did not worsen the condition number, and the sampled
    trajectory stays within the robot file's limits."""
    doc = json.loads((out / "excitation.json").read_text())
    FourierTrajectory.from_dict(doc["trajectory"])
    assert doc["condition_optimized"] <= doc["condition_initial"], doc["condition_optimized"]
    traj = pd.read_csv(out / "traj.csv")
    assert len(traj) == int(PERIOD_S * 1000) + 1  # --rate 1000 over one period, both ends
    q = traj[[f"position_{j}" for j in robot.joint_names]].to_numpy()
    dq = traj[[f"velocity_{j}" for j in robot.joint_names]].to_numpy()
    assert np.all(q >= robot.lower_limit) and np.all(q <= robot.upper_limit)
    assert np.all(np.abs(dq) <= robot.velocity_limit)


def check_recorded_log(out: Path, robot: Any) -> None:
    """excite --record: the log reads back for this arm, one period long, and is the plant following the
    excitation exported beside it."""
    traj = pd.read_csv(out / "traj.csv")
    q = traj[[f"position_{j}" for j in robot.joint_names]].to_numpy()
    log = load_log(out / "log.csv", joint_names=robot.joint_names)
    assert log.q.shape == (log.t.size, robot.n)
    # one period at 1 kHz; the recorder leaves out up to two ticks at the ends (measured: 9,999 samples,
    # 0..9.998 s); 1e-9 s for the round-off of the written time stamps
    assert abs(log.t[-1] - PERIOD_S) <= 2e-3 + 1e-9, log.t[-1]
    # the log's positions are the trajectory's to within the impedance controller's tracking error
    # (k = 300 Nm/rad against model errors of +-10 %); 0.1 rad separates following from a wrong joint
    # order or a log of another motion (swings of ~1 rad)
    q_ref = np.column_stack([np.interp(log.t, traj["t"], q[:, j]) for j in range(robot.n)])
    assert np.abs(log.q - q_ref).max() < 0.1, np.abs(log.q - q_ref).max(axis=0)


def check_friction(out: Path, robot: Any, speeds: tuple[float, ...]) -> None:
    """identify friction: each identified joint's Coulomb + viscous curve at the run speeds is the plant's;
    the joints not run (Atlas' wrist by default) are null, never a silent 0."""
    doc = json.loads((out / "friction.json").read_text())
    assert doc["joint_names"] == robot.joint_names
    ids = [j - 1 for j in doc["identified_joints"]]  # 1-based in the file
    assert ids and 0 in ids, doc["identified_joints"]
    for j in set(range(robot.n)) - set(ids):
        assert doc["coulomb"][j] is None and doc["viscous"][j] is None, (j + 1, doc["coulomb"], doc["viscous"])
    coulomb, viscous = (np.asarray([doc[k][j] for j in ids], dtype=float) for k in ("coulomb", "viscous"))
    fitted = coulomb[:, None] + np.outer(viscous, speeds)
    true = robot.friction.coulomb[ids, None] + np.outer(robot.friction.viscous[ids], speeds)
    np.testing.assert_allclose(
        fitted, true, atol=FRICTION_ATOL_NM, rtol=FRICTION_RTOL, err_msg="friction torque at the run speeds"
    )


def check_model_files(out: Path, options: list[str], robot: Any) -> dict[str, Any]:
    """identify dynamics: each model file loads on its own (the robot file found relative to it, with
    the cut) for the arm's joints."""
    models = {}
    for method in ("sequential", "combined"):
        path = out / f"model_{method}.json"
        source = json.loads(path.read_text())["robot"]["source"]
        if options[1] != "panda":
            assert not Path(source).is_absolute(), source  # the folder can move with its robot file
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the robot file's notes again, as load_from_options
            models[method] = load_identified_model(path)
        assert models[method].joint_names == robot.joint_names
    return models


def check_robot_copies(out: Path, options: list[str], robot: Any, models: dict[str, Any]) -> None:
    """Write-back: the robot file copy beside each model file loads with the same options and has the
    model's dynamics (M(q), g(q), friction)."""
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(robot.lower_limit), robot.lower_limit, -np.pi)
    hi = np.where(np.isfinite(robot.upper_limit), robot.upper_limit, np.pi)
    postures = rng.uniform(lo, hi, size=(5, robot.n))
    for method, model in models.items():
        (copy,) = out.glob(f"robot_{method}.*")
        written = load_from_options(options, source=str(copy), ee_frame=robot.ee_frame)
        # the copy holds the model's link parameters and friction, written with 12 significant digits:
        # M(q) and g(q) agree to 1e-9 of their scale (round-off of the written numbers, not of the method)
        for q in postures:
            m = model.compute_mass_matrix(q)
            np.testing.assert_allclose(written.compute_mass_matrix(q), m, rtol=0, atol=1e-9 * np.abs(m).max())
            g = model.compute_gravity(q)
            np.testing.assert_allclose(written.compute_gravity(q), g, rtol=0, atol=1e-9 * max(np.abs(g).max(), 1.0))
        np.testing.assert_allclose(written.friction.coulomb, model.friction.coulomb, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(written.friction.viscous, model.friction.viscous, rtol=1e-9, atol=1e-12)


def prediction_rmse(log_path: Path, robot: Any, models: dict[str, Any]) -> dict[str, float]:
    """Pooled RMSE of the torques each model predicts on a log, evaluated as the controller evaluates
    it (RobotModel.compute_motor_torque: its friction with its velocity band), on the states ``validate``
    uses (low-pass 10 Hz), at every 10th sample."""
    from reflexarm.ident import preprocess_log

    raw = load_log(log_path, joint_names=robot.joint_names)
    states = preprocess_log(raw, cutoff_hz=10.0)
    assert states.ddq is not None  # preprocess_log differentiates dq
    idx = np.arange(0, states.t.size, 10)
    meas = np.column_stack([np.interp(states.t[idx], raw.t, raw.tau[:, j]) for j in range(robot.n)])
    out = {}
    for name, model in models.items():
        pred = np.array([model.compute_motor_torque(states.q[i], states.dq[i], states.ddq[i]) for i in idx])
        out[name] = float(np.sqrt(np.mean((pred - meas) ** 2)))
    return out


def check_validation(out: Path, log_path: Path, robot: Any, identified: Any) -> None:
    """validate: a row per joint; and the identified model predicts the held-out torques near the floor of
    the robot file's exact parameters and better than the model the experiment commands run by default
    (the file's parameters with the paper's +-10 % errors, --model-seed 0), all evaluated the same way."""
    from reflexarm.robots import perturb_model

    doc = json.loads((out / "validate.json").read_text())["validation"]
    assert [r["joint"] for r in doc["rows"]] == robot.joint_names
    assert np.isfinite(doc["pooled_rmse"]) and doc["pooled_rmse"] > 0
    models = {"identified": identified, "exact": robot, "nominal": perturb_model(robot, 0.1, seed=0)}
    rmse = prediction_rmse(log_path, robot, models)
    assert rmse["identified"] <= FLOOR_FACTOR * rmse["exact"], rmse
    assert rmse["identified"] < rmse["nominal"], rmse


def check_thresholds(out: Path, free_motion: dict[str, Any], n: int) -> np.ndarray:
    """tune-thresholds: finite positive levels per joint, the contact level below the collision level, and
    the collision level above every residual of the free motion it was tuned on (no alarm on its own log)."""
    doc = json.loads((out / "thresholds.json").read_text())
    collision = np.asarray(doc["collision_Nm"], dtype=float)
    contact = np.asarray(doc["contact_Nm"], dtype=float)
    assert collision.shape == contact.shape == (n,)
    assert np.all(np.isfinite(collision)) and np.all(contact > 0), (collision, contact)
    assert np.all(contact < collision), (contact, collision)
    assert [j["joint"] for j in doc["joints"]] == list(range(1, n + 1))  # 1-based for people
    assert all(j["collision_alarms_in_logs"] == 0 for j in doc["joints"]), doc["joints"]
    # the online residual of the same run (the controller's, with the measured noise) is what --recorded-residual
    # tunes on: a level meant for 1 false alarm per hour is not below its maximum (a fitted level that falls
    # below is raised to it, with a note; an alarm needs |r| > zeta)
    assert np.all(collision >= np.asarray(free_motion["max_abs_residual_Nm"])), (collision, free_motion)
    return collision


def check_demo(out: Path) -> None:
    """demo: the block is hit in all three runs, and Coll.Det detects it after the contact, not before."""
    rows = {r["run"]: r for r in json.loads((out / "ee_collision_summary.json").read_text())}
    assert set(rows) == {"Stiff", "Compliant", "Coll.Det"}
    for name, row in rows.items():
        assert row["peak_force_N"] > CONTACT_FORCE_N and row["first_contact_s"] is not None, (name, row)
    det = rows["Coll.Det"]
    assert det["detection_s"] is not None and det["detection_s"] >= det["first_contact_s"], det
    assert rows["Stiff"]["detection_s"] is None  # detection off
    assert (out / "ee_collision_still.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def check_link_collision(out: Path, n: int) -> None:
    """simulate link-collision: the stick touches the link and the push is detected after the contact, on
    joints up to the pushed link's (joint ceil(n/2) by default; the joints beyond it feel no torque)."""
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["contact_start_s"] is not None and row["peak_external_torque_Nm"] > 1.0, row
    assert row["detection_s"] is not None and row["detection_s"] >= row["contact_start_s"], row
    assert row["detected_joints"] and set(row["detected_joints"]) <= set(range(1, (n + 1) // 2 + 1)), row


def check_efc_step(out: Path) -> None:
    """efc-step: the 50 N step moves the arm without DC, DC stiffens it (10), EFC gives the compliance back
    (11). Bounds as test_any_arm_experiments: DC below 10 % of the displacement, EFC within 25 % of it
    (2.3 N force noise on a 50 N step and +-10 % model errors)."""
    doc = json.loads((out / "efc_step.json").read_text())
    rows = {r["run"]: r for r in doc["rows"]}
    assert rows["no DC"]["ee_displacement_mm"] > 1.0, rows["no DC"]
    s = doc["summary"]
    assert s["dc_vs_nodc_displacement"] < 0.1, s
    assert 0.75 < s["efc_vs_nodc_displacement"] < 1.25, s


@pytest.mark.slow
@pytest.mark.parametrize("arm", [arm_param(arm) for arm in ARMS])
def test_the_whole_workflow_from_the_command_line(arm, tmp_path):
    options = robot_options(arm, tmp_path)
    steps = Steps(arm)
    robot = load_from_options(options)
    exc, val, fr, dyn = (tmp_path / name for name in ("exc", "val", "friction", "dyn"))
    # the excitation optimizer, briefly: coefficients and the trajectory a robot plays (CSV)
    run(["excite", *options, "--harmonics", "3", "--maxiter", "5", "--periods", "1", "--out", str(tmp_path / "opt"),
         "--csv", str(tmp_path / "opt" / "traj.csv"), "--quiet"])  # fmt: skip
    steps.check("excite", check_excitation, tmp_path / "opt", robot)
    # the identification log: an excitation run on the plant. Its seeded random start (--maxiter 0), as an
    # optimized one depends on the machine's floating point (as 'identify dynamics --help' says)
    run(["excite", *options, "--harmonics", "3", "--maxiter", "0", "--seed", "0", "--periods", "1", "--out", str(exc),
         "--record", str(exc / "log.csv"), "--csv", str(exc / "traj.csv"), "--quiet"])  # fmt: skip
    steps.check("excite --record", check_recorded_log, exc, robot)
    # a held-out log: another seeded start, other sensor noise
    run(["excite", *options, "--harmonics", "3", "--maxiter", "0", "--seed", "1", "--periods", "1",
         "--out", str(val), "--record", str(val / "log.csv"), "--quiet"])  # fmt: skip
    speeds = ",".join(f"{v:g}" for v in FRICTION_SPEEDS)
    run(["identify", "friction", *options, "--speeds", speeds, "--out", str(fr), "--quiet"])
    steps.check("identify friction", check_friction, fr, robot, FRICTION_SPEEDS)
    run(["identify", "dynamics", *options, "--log", str(exc / "log.csv"), "--split", "0.7", "--friction",
         str(fr / "friction.json"), "--method", "both", "--out", str(dyn), "--quiet"])  # fmt: skip
    models = steps.check("model files", check_model_files, dyn, options, robot)
    model = str(dyn / "model_sequential.json")
    run(["validate", *options, "--model", model, "--log", str(val / "log.csv"), "--out", str(tmp_path / "vd"),
         "--quiet"])  # fmt: skip
    steps.check("validate", check_validation, tmp_path / "vd", val / "log.csv", robot, models["sequential"])
    # thresholds from a free-motion log of the arm under the identified model
    fm, tt = tmp_path / "free", tmp_path / "thresholds"
    duration = FREE_MOTION_CYCLES * free_motion_trajectory(1.0, "demo", robot).duration  # one cycle at least
    run(["simulate", "free-motion", *options, "--model", model, "--duration", f"{duration:.3f}", "--out", str(fm),
         "--quiet"])  # fmt: skip
    free_motion = json.loads((fm / "free_motion.json").read_text())
    run(["tune-thresholds", str(fm / "free_motion_trace.parquet"), *options, "--model", model,
         "--recorded-residual", "--allow-extrapolation", "--no-figure", "--out", str(tt)])  # fmt: skip
    steps.check("tune-thresholds", check_thresholds, tt, free_motion, robot.n)
    (fm / "free_motion_trace.parquet").unlink()  # ~0.5 MB per simulated second; pytest keeps 3 runs' tmp_path
    # the closed-loop experiments with the identified model
    run(["demo", *options, "--model", model, "--out", str(tmp_path / "demo"), "--quiet"])
    steps.check("demo", check_demo, tmp_path / "demo")
    run(["simulate", "link-collision", *options, "--model", model, "--out", str(tmp_path / "link"), "--quiet"])
    steps.check("link-collision", check_link_collision, tmp_path / "link", robot.n)
    # efc-step with the experiments' +-10 % model: disturbance compensation feeds the residual back, and a
    # 7 s random-start excitation leaves M(q) poorly determined (iiwa14: eigenvalues of M^-1 M_hat down to
    # 0.02, the DC runs diverge); the torques validate regardless, as gravity dominates them
    run(["efc-step", *options, "--out", str(tmp_path / "efc"), "--quiet"])
    steps.check("efc-step", check_efc_step, tmp_path / "efc")
    # last, as it is no input of the steps above: the robot file copies (write-back)
    steps.check("robot copies", check_robot_copies, dyn, options, robot, models)
    steps.finish()
