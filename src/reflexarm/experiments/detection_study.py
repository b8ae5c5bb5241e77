"""Detection study (issue 15, item 5): the detection observer's gain and levels against lag and false alarms.

Per arm of :data:`~reflexarm.experiments.reaction_study.STUDY_ARMS`, three disjoint sets of seeds (model
errors +-10 % and the paper's sensor noise):

* **A, tuning**: free-motion logs (``motion``, :func:`~reflexarm.experiments.collision.free_motion_trajectory`)
  of ``tune_models`` model seeds; :func:`~reflexarm.tuning.propose_detection_pairs` gives the per-joint levels
  of every gain for ``rate_per_hour`` false alarms of the arm.
* **C, false alarms**: ``heldout_s`` (default one hour) of free motion; the alarms of every pair are counted on
  its residual (the held-out logs of the pairs).
* **B, contacts**: the demo's end-effector contact and the link collision, run with each pair (exact observer,
  reaction (13)); the detection lag = t_detect - the first time the true |tau_ext_j| exceeds zeta_j on any joint
  (negative: detected before), and on the detecting joints, the contact-to-detection delay of
  :func:`~reflexarm.experiments.collision_events.collision_outcome` beside it. The contacts run once per noise seed
  B, B + 1, ... (``contact_seeds``): one seed's lag is one draw of the sensor noise (on Atlas at 100 1/s the
  detecting joint's lag was 10 ms with seed B and 11-56 ms, or no crossing at all, with the next nine);
  :func:`lag_spread` gives the median, the largest and the share within :data:`TARGET_LAG_S`. And short impacts,
  ``pulses`` force pulses of 10-30 ms on random links during free motion (:class:`~reflexarm.sim.LinkForce`), caught
  when a joint's residual crosses its level during the pulse or :data:`PULSE_GRACE_S` after it.

The free-motion runs are compiled closed loops with the observer at the largest gain (exact form, detection
off, reaction "none"), in chunks of ``chunk_s`` (the controller restarts each chunk); every other gain's
residual is the same controller's at that gain (:func:`~reflexarm.tuning.refilter`, equal to a replay to
round-off). The "model error" a pulse is compared with is the largest |residual| of the slow observer (the
first gain) in the tuning logs, per joint: what the model errors and friction leave after the filter. The
residual noise grows with the gain as k_o M(q) sigma_dq; :func:`noise_growth` measures it per joint.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.detect.defaults import DETECTION_LAG_TARGET_S
from reflexarm.errors import ConfigError
from reflexarm.experiments.collision import CollisionSetting, controller_model, free_motion_trajectory
from reflexarm.experiments.reaction_study import STUDY_ARMS, StudyArm, study_arm
from reflexarm.robots import CoulombViscousFriction
from reflexarm.sim import PAPER_NOISE, Plant, Trace
from reflexarm.tuning import DEFAULT_DETECTION_GAINS, ObserverSettings, ResidualReplay, refilter

__all__ = [
    "PULSE_GRACE_S",
    "DetectionSetting",
    "DetectionStudy",
    "contact_lag",
    "free_motion_residuals",
    "input_lag",
    "lag_spread",
    "noise_growth",
    "observer_input",
    "run_detection_study",
    "study_arm_detection",
]

#: Target of issue 15: detection at most this long after the true external torque exceeds the level [s].
TARGET_LAG_S = DETECTION_LAG_TARGET_S
#: A pulse counts as caught when a residual crosses its level up to this long after the pulse ends [s].
PULSE_GRACE_S = 0.010
#: Noise seeds of each pair's contact runs (B, B + 1, ...).
DEFAULT_CONTACT_SEEDS = 10
#: Seed offsets of the three disjoint sets: tuning (A), contacts and pulses (B), the false-alarm hour (C).
SEEDS = {"A": 1000, "B": 2000, "C": 3000}
#: How the runs' model errors are drawn (``model_seeds=``): one arm for all, or one model per seed.
MODEL_SEEDS = ("same", "disjoint")
#: The model seed of "the arm" when every run shares one (``model_seeds="same"``): disjoint from every
#: noise and motion seed of :data:`SEEDS`.
ARM_MODEL_SEED = 7


@dataclass(frozen=True)
class DetectionSetting(CollisionSetting):
    """A :class:`~reflexarm.experiments.collision.CollisionSetting` whose controller runs the observers in
    ``observer_discretization`` (default "exact", stable at any gain)."""

    observer_discretization: str = "exact"


def _plant(arm: StudyArm, seed: int, scene: Any = None) -> Plant:
    friction = CoulombViscousFriction.zeros(arm.robot.n) if arm.plant_friction == "none" else None
    return Plant(arm.robot, scene=scene, noise=PAPER_NOISE, seed=seed, true_friction=friction)


def free_motion_residuals(
    arm: StudyArm,
    duration: float,
    *,
    gain: float,
    model_seed: int,
    seed: int,
    motion: str = "loaded",
    chunk_s: float = 300.0,
    scene: Any = None,
    keep: Callable[[Trace], None] | None = None,
    motion_seed: int | None = None,
    detection_friction_band: float | None = None,
) -> list[ResidualReplay]:
    """Free motion of ``arm`` for ``duration`` [s] (model errors +-10 % of ``model_seed``, noise ``seed``),
    compiled, the detection observer at ``gain`` (exact), in chunks of ``chunk_s``: one replay per chunk
    (the controller's online residual; :func:`~reflexarm.tuning.refilter` gives other gains). ``keep`` sees
    each chunk's trace (e.g. the true external torque of a ``scene``); ``motion_seed`` varies the motion
    (:func:`~reflexarm.experiments.collision.free_motion_trajectory`; None: the fixed cycle);
    ``detection_friction_band``: the detection observer's own friction model (``CollisionSetting``)."""
    from reflexarm.sim.compiled_loop import run_fast

    model, _ = controller_model(arm.robot, 0.1, model_seed, None)
    traj = free_motion_trajectory(duration, motion, arm.robot, seed=motion_seed)
    plant = _plant(arm, seed, scene)
    plant.reset(traj.sample(0.0).q_d)
    ctrl = DetectionSetting("free motion", stiffness=300.0, detection_observer_gain=gain, threshold=None,
                            reaction="none", detection_friction_band=detection_friction_band).controller(model)
    out, done = [], 0.0
    while done < duration - 1e-9:
        span = min(chunk_s, duration - done)
        trace = run_fast(plant, ctrl, traj, span)
        name = (
            f"{arm.name} free motion {motion} (motion seed {motion_seed}) model seed {model_seed} noise seed {seed}"
            f" [{done:g}, {done + span:g}] s"
        )
        dt = float(np.median(np.diff(trace.t)))
        out.append(ResidualReplay(name, trace.t.copy(), trace.residual.copy(), dt, 0, (), gain, "exact"))
        if keep is not None:
            keep(trace)
        done += span
        del trace
    return out


def noise_growth(replays: Sequence[ResidualReplay], gains: Sequence[float]) -> dict[str, Any]:
    """Per gain and joint: the residual's standard deviation and its largest |value| in ``replays`` [Nm]
    (the growth ~ k_o M(q) sigma_dq of the velocity noise passed by (4))."""
    rows = []
    for k in gains:
        reps = [refilter(r, k) for r in replays]
        res = np.concatenate([r.residual for r in reps])
        rows.append(
            {"gain": float(k), "std_Nm": res.std(axis=0).tolist(), "max_abs_Nm": np.abs(res).max(axis=0).tolist()}
        )
    return {"rows": rows}


def _crossing_lags(trace: Trace, over: np.ndarray) -> dict[str, Any]:
    """For ``over`` (N, n), where a signal exceeds its joint's level: the first crossing on any joint, the
    detection lag after it (None without a detection or a crossing), the detecting joints (1-based) and the
    lag after the first crossing among them (both None without a detection). With a detection only crossings up
    to its tick count: what follows is the reaction's run (e.g. a second strike after (13)), not the detector's."""
    t = trace.t
    i_d = int(np.argmax(trace.collision)) if trace.collision.any() else None
    if i_d is not None:
        over = over[: i_d + 1]
    first = [int(np.argmax(over[:, j])) if over[:, j].any() else None for j in range(over.shape[1])]
    crossings = [t[i] for i in first if i is not None]
    out: dict[str, Any] = {"detected_s": None if i_d is None else float(t[i_d])}
    out["crossing_s"] = float(min(crossings)) if crossings else None
    out["lag_s"] = None if i_d is None or not crossings else float(t[i_d]) - out["crossing_s"]
    out["joints"] = out["joint_lag_s"] = None
    if i_d is not None:
        joints = np.flatnonzero(trace.collided[i_d])
        lags = [float(t[i_d] - t[first[j]]) for j in joints if first[j] is not None]
        out["joints"], out["joint_lag_s"] = [int(j) + 1 for j in joints], min(lags) if lags else None
    return out


def contact_lag(trace: Trace, levels: np.ndarray) -> dict[str, Any]:
    """Detection lag of a run: t_detect - the first time, up to detection, that the true |tau_ext_j| exceeds
    zeta_j on any joint [s] (None without detection or without a true crossing up to it: detected before the true
    torque reached the level), and on the joints that crossed at detection (the detecting joints)."""
    c = _crossing_lags(trace, np.abs(trace.tau_ext) > levels)
    row: dict[str, Any] = {"detected_s": c["detected_s"], "true_crossing_s": c["crossing_s"], "lag_s": c["lag_s"]}
    if c["detected_s"] is not None:
        row["detecting_joints"], row["lag_detecting_joint_s"] = c["joints"], c["joint_lag_s"]
    row["peak_abs_tau_ext_Nm"] = np.abs(trace.tau_ext).max(axis=0).tolist()
    return row


#: Gain [1/s] of the replay that stands for the detection observer's *input* (``observer_input``): exact form,
#: k_o dt = 10 at 1 kHz, so each tick's output is its own input to e^-10 = 4.5e-5 (no filter lag).
INPUT_GAIN = 1e4


def observer_input(trace: Trace, setting: CollisionSetting, model: Any) -> np.ndarray:
    """The disturbance the detection observer filters along a run, (N, n) [Nm]: the true external torque plus
    what the controller's model gets wrong (rigid body, friction) at the run's states.

    The run's controller (``setting`` on ``model``: its kappas, its friction model) replayed on the plant's
    true, noise-free q and dq and the measured motor torque (noise 0.07 Nm) with the detecting observer at
    :data:`INPUT_GAIN` (exact form) and no second stage: the observer with its filter taken out."""
    from reflexarm.control import replay

    probe = replace(setting, detection_observer_gain=INPUT_GAIN, observer_discretization="exact", threshold=None,
                    reaction="none", detection_filter_gain=None).controller(model)  # fmt: skip
    return replay(probe, trace.t, trace.q, trace.dq, trace.tau_m, trace.wrench).residual


def input_lag(trace: Trace, levels: np.ndarray, disturbance: np.ndarray, contact_s: float | None) -> dict[str, Any]:
    """The detector's own lag: t_detect - the first time at or after contact that the observer's input
    (:func:`observer_input`) exceeds zeta_j on any joint, and on the detecting joints [s] (None without a
    detection or a crossing). Unlike :func:`contact_lag` it does not count the time a contact needs to
    outgrow a model-error bias of the other sign, which depends on how fast the contact builds up."""
    after = trace.t >= (contact_s if contact_s is not None else np.inf)
    c = _crossing_lags(trace, (np.abs(disturbance) > levels) & after[:, None])
    return {
        "input_crossing_s": c["crossing_s"],
        "input_lag_s": c["lag_s"],
        "input_lag_detecting_joint_s": c["joint_lag_s"],
    }


@dataclass
class DetectionStudy:
    """The study's results per arm (JSON-ready dicts) and its conditions."""

    arms: dict[str, dict[str, Any]] = field(default_factory=dict)
    conditions: dict[str, Any] = field(default_factory=dict)

    def rows(self) -> list[dict[str, Any]]:
        """One flat row per (arm, gain): levels, lags, false alarms, contacts, pulses caught."""
        rows = []
        for name, a in self.arms.items():
            for p in a["pairs"]["pairs"]:
                k = p["detection_observer_gain"]
                h = p["heldout"] or {}
                kf = p.get("detection_filter_gain")
                row = {"arm": name, "gain_per_s": k, "filter_gain_per_s": kf,
                       "time_constant_s": 1.0 / k + (0.0 if kf is None else 1.0 / kf),
                       "max_collision_Nm": max(p["collision_Nm"]), "min_collision_Nm": min(p["collision_Nm"]),
                       "ramp_lag_max_s": p["ramp_lag_max_s"], "step_lag_s": p["step_lag_s"],
                       "measured_step_lag_median_s": p["measured_step_lag_median_s"],
                       "measured_step_lag_max_s": p["measured_step_lag_max_s"],
                       "measured_ramp_lag_median_s": p["measured_ramp_lag_median_s"],
                       "measured_ramp_lag_max_s": p["measured_ramp_lag_max_s"],
                       "heldout_hours": h.get("duration_s", 0.0) / 3600.0, "false_alarms": h.get("alarms"),
                       "false_alarms_per_hour": h.get("alarms_per_hour")}  # fmt: skip
                for scen, c in a.get("contacts", {}).get(str(k), {}).items():
                    row[f"{scen}_lag_s"], row[f"{scen}_delay_s"] = c.get("lag_s"), c.get("delay_s")
                    row[f"{scen}_input_lag_s"] = c.get("input_lag_s")
                    row[f"{scen}_lag_detecting_joint_s"] = c.get("lag_detecting_joint_s")
                for scen, sp in a.get("contact_seeds", {}).get(str(k), {}).items():  # over the noise seeds
                    row[f"{scen}_joint_lag_median_s"], row[f"{scen}_joint_lag_max_s"] = sp["median_s"], sp["max_s"]
                    row[f"{scen}_within_target"], row[f"{scen}_seeds"] = sp["within_target"], sp["seeds"]
                    row[f"{scen}_delay_median_s"], row[f"{scen}_delay_max_s"] = sp["delay_median_s"], sp["delay_max_s"]
                pul = a.get("pulses", {}).get("caught", {}).get(str(k))
                if pul is not None:
                    row["pulses_caught_share"], row["pulses_eligible"] = pul["share_eligible"], pul["eligible"]
                rows.append(row)
        return rows

    def write(self, folder: str | Path, name: str = "detection_study") -> dict[str, Path]:
        """``{name}.json``, ``{name}.csv`` and the trade-off figure ``{name}.png`` into ``folder``."""
        import pandas as pd

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"json": out / f"{name}.json", "csv": out / f"{name}.csv", "figure": out / f"{name}.png"}
        paths["json"].write_text(json.dumps({"conditions": self.conditions, "arms": self.arms}, indent=2))
        pd.DataFrame(self.rows()).to_csv(paths["csv"], index=False, float_format="%.6g")
        from reflexarm.experiments.detection_plots import plot_tradeoff

        plot_tradeoff(self, paths["figure"])
        return paths


def lag_spread(runs: Sequence[dict[str, Any]], key: str = "lag_detecting_joint_s") -> dict[str, Any]:
    """Over the runs of one scenario and pair with several noise seeds (rows of :func:`contact_lag`): the lags
    ``key`` [s] per seed (None: not detected, or the detecting joints' true torque never exceeded its level), the
    median and the largest over the seeds with a lag, how many are within :data:`TARGET_LAG_S` (a negative lag,
    detected before the true torque crossed, counts as within), how many were detected without a true crossing on the
    detecting joints, and how many not at all; beside them the contact-to-detection delays (``delay_s``) per seed and
    their median and largest over the detected runs."""
    lags = [r.get(key) for r in runs]
    have = np.array([v for v in lags if v is not None], dtype=float)
    delays = [r.get("delay_s") for r in runs]
    found = np.array([v for v in delays if v is not None], dtype=float)
    return {
        "delays_s": delays,
        "delay_median_s": float(np.median(found)) if found.size else None,
        "delay_max_s": float(found.max()) if found.size else None,
        "lags_s": lags,
        "seeds": len(runs),
        "median_s": float(np.median(have)) if have.size else None,
        "max_s": float(have.max()) if have.size else None,
        "within_target": int(np.sum(have <= TARGET_LAG_S + 1e-9)),
        "detected_without_crossing": sum(1 for r, v in zip(runs, lags, strict=True)
                                         if v is None and r.get("detected_s") is not None),  # fmt: skip
        "undetected": sum(1 for r in runs if r.get("detected_s") is None),
    }


def _contact_runs(
    arm: StudyArm, gain: float, levels: np.ndarray, seed: int, model_seed: int, band: float | None = None,
    filter_gain: float | None = None,
) -> dict[str, Any]:
    """The demo contact and the link collision with the pair (gain, levels), noise seed ``seed`` (B) on the
    model of ``model_seed`` (``band``: the detection observer's friction band, None: none; ``filter_gain``: the
    detection residual's second stage K_f, None: none); lag and delay each."""
    from reflexarm.experiments.collision import run_ee_collision, run_link_collision
    from reflexarm.experiments.collision_events import collision_outcome

    setting = DetectionSetting(
        "Coll.Det", stiffness=300.0, observer_gain=5.0, detection_observer_gain=gain,
        threshold=tuple(float(v) for v in levels), reaction="gravity", detection_friction_band=band,
        detection_filter_gain=filter_gain,
    )  # fmt: skip
    model, _ = controller_model(arm.robot, 0.1, model_seed, None)
    kw: dict[str, Any] = {"robot": arm.robot, "model_error": 0.1, "model_seed": model_seed, "seed": seed,
          "plant_friction": arm.plant_friction}  # fmt: skip
    out = {}
    for scen, run in (("demo", run_ee_collision), ("link", run_link_collision)):
        trace = run(setting=setting, **kw)  # type: ignore[operator, unused-ignore]
        row = contact_lag(trace, levels)
        event = collision_outcome(trace, arm.robot, name=f"{arm.name}/{scen}/k_o {gain:g}")
        row.update({"contact_s": event.contact_s, "delay_s": event.delay_s, "contact_class": event.contact_class})
        row.update(input_lag(trace, levels, observer_input(trace, setting, model), event.contact_s))
        out[scen] = row
    return out


def _pulse_scene(arm: StudyArm, count: int, rng: np.random.Generator) -> tuple[list[Any], list[dict[str, Any]]]:
    """``count`` LinkForce pulses of 10-30 ms, 20-300 N (log-uniform), random direction and link, 1.5 s apart."""
    import mujoco

    from reflexarm.sim import LinkForce

    plant = _plant(arm, 0)
    bodies = [mujoco.mj_id2name(plant.model, mujoco.mjtObj.mjOBJ_BODY, int(plant.model.joint(j).bodyid[0]))
              for j in plant.joint_names[1:]]  # fmt: skip
    scenes, specs = [], []
    for i in range(count):
        t_on = 2.0 + 1.5 * i + float(rng.uniform(0.0, 0.5))
        width = float(rng.uniform(0.010, 0.030))
        u = rng.normal(size=3)
        force = float(np.exp(rng.uniform(np.log(20.0), np.log(300.0))))
        spec = {"t_on_s": t_on, "t_off_s": t_on + width, "body": bodies[int(rng.integers(len(bodies)))],
                "force_N": force, "direction": (u / np.linalg.norm(u)).tolist()}  # fmt: skip
        scenes.append(LinkForce(spec["body"], spec["force_N"], t_on, t_on + width, direction=spec["direction"]))
        specs.append(spec)
    return scenes, specs


def _pulses(
    arm: StudyArm, pairs: Any, model_error: np.ndarray, count: int, seed: int, model_seed: int,
    band: float | None = None, filter_gain: float | None = None,
) -> dict[str, Any]:
    """Short impacts during free motion: the share caught by each pair, among pulses whose true joint torque
    peaks above 3x the model error of some joint ("eligible") and among all."""
    scenes, specs = _pulse_scene(arm, count, np.random.default_rng(seed))
    traces: list[Trace] = []
    gains = [p.gain for p in pairs.pairs]
    (rep,) = free_motion_residuals(arm, 2.0 + 1.5 * count + 1.0, gain=max(gains), model_seed=model_seed, seed=seed,
                                   chunk_s=1e9, scene=scenes, keep=traces.append, motion_seed=seed,
                                   detection_friction_band=band)  # fmt: skip
    t, tau_ext = traces[0].t, traces[0].tau_ext
    caught: dict[str, dict[str, Any]] = {}
    for p in pairs.pairs:
        r = refilter(rep, p.gain, filter_gain=filter_gain).residual
        hits = []
        for s in specs:
            on = (t >= s["t_on_s"]) & (t <= s["t_off_s"])
            win = (t >= s["t_on_s"]) & (t <= s["t_off_s"] + PULSE_GRACE_S)
            s["ratio_to_model_error"] = float(np.max(np.abs(tau_ext[on]).max(axis=0) / model_error))
            hits.append(bool(np.any(np.abs(r[win]) > p.collision)))
        ok = np.array(hits)
        elig = np.array([s["ratio_to_model_error"] >= 3.0 for s in specs])
        caught[str(p.gain)] = {"caught": int(ok.sum()), "pulses": len(specs), "eligible": int(elig.sum()),
                               "caught_eligible": int((ok & elig).sum()),
                               "share_eligible": float((ok & elig).sum() / elig.sum()) if elig.any() else None,
                               "share_all": float(ok.mean()), "hits": hits}  # fmt: skip
    return {"specs": specs, "model_error_Nm": model_error.tolist(), "caught": caught}


def study_arm_detection(
    arm: StudyArm,
    gains: Sequence[float] = DEFAULT_DETECTION_GAINS,
    *,
    tune_s: float = 600.0,
    tune_models: int = 3,
    heldout_s: float = 3600.0,
    pulses: int = 40,
    rate_per_hour: float = 0.1,
    chunk_s: float = 300.0,
    motion: str = "loaded",
    model_seeds: str = "same",
    contact_seeds: int = DEFAULT_CONTACT_SEEDS,
    detection_friction_band: float | None = None,
    detection_filter_gain: float | None = None,
) -> dict[str, Any]:
    """One arm of the study (module docstring): pairs, false alarms, noise growth, contacts, pulses.

    ``model_seeds``: "same" (default) gives every run the model of one seed (:data:`ARM_MODEL_SEED`): one
    arm with its model errors, tuned on its own logs (other motion and noise seeds) as a user tunes on the
    robot; "disjoint" gives the tuning, held-out and contact runs models of their own seeds (the levels must
    then cover another arm's model errors too). ``contact_seeds``: noise seeds of the contact runs (>= 1).
    ``detection_friction_band`` [rad/s]: every run's detection observer subtracts the friction model in this
    velocity band (``Controller(detection_kappa_f=1)``), the levels are tuned on that residual; None: the
    paper's (kappa_f = 0). ``detection_filter_gain`` [1/s]: every pair's detector looks at its residual through
    the second stage K_f (``Controller(detection_filter_gain=)``; pairs (k_o, K_f), tuned on that residual); the
    free-motion runs record the first order, which :func:`~reflexarm.tuning.refilter` takes to each pair's
    cascade. The model error and the noise growth stay the first order's."""
    import warnings

    from reflexarm.tuning import ThresholdWarning, propose_detection_pairs
    from reflexarm.tuning.replay import check_filter_gain

    if isinstance(contact_seeds, bool) or not isinstance(contact_seeds, int) or contact_seeds < 1:
        raise ConfigError(f"contact_seeds must be an integer >= 1; got {contact_seeds!r}")
    if model_seeds not in MODEL_SEEDS:
        raise ConfigError(f"model_seeds must be one of {', '.join(MODEL_SEEDS)}; got {model_seeds!r}")
    check_filter_gain(detection_filter_gain)  # a bad K_f refused before the minutes of runs
    same = model_seeds == "same"

    def model_of(seed: int) -> int:
        return ARM_MODEL_SEED if same else seed

    ref = max(gains)
    band, kf = detection_friction_band, detection_filter_gain
    fm = {"gain": ref, "motion": motion, "chunk_s": chunk_s, "detection_friction_band": band}
    tune = [r for i in range(tune_models) for r in free_motion_residuals(
        arm, tune_s, model_seed=model_of(SEEDS["A"] + i), seed=SEEDS["A"] + i, motion_seed=SEEDS["A"] + i,
        **fm)]  # type: ignore[arg-type]  # fmt: skip
    held = free_motion_residuals(arm, heldout_s, model_seed=model_of(SEEDS["C"]), seed=SEEDS["C"],
                                 motion_seed=SEEDS["C"], **fm)  # type: ignore[arg-type]  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ThresholdWarning)
        pairs = propose_detection_pairs(tune, arm.robot, gains, heldout=held, rate_per_hour=rate_per_hour,
                                        allow_extrapolation=True,
                                        settings=ObserverSettings(detection_friction_band=band,
                                                                  detection_filter_gain=kf))  # fmt: skip
    slow = [refilter(r, min(gains)) for r in tune]
    model_error = np.max([np.abs(r.residual[int(5 / min(gains) / r.dt) :]).max(axis=0) for r in slow], axis=0)
    out: dict[str, Any] = {"plant_friction": arm.plant_friction, "joints": arm.robot.joint_names,
                           "pairs": pairs.as_dict(), "noise_growth": noise_growth(held[:1], gains),
                           "warnings": sorted({str(w.message) for w in caught})[:20]}  # fmt: skip
    out["model_seeds"] = {"mode": model_seeds, "arm_model_seed": ARM_MODEL_SEED if same else None}
    out["detection_friction_band"], out["detection_filter_gain"] = band, kf
    out["contacts"], out["contact_seeds"] = {}, {}
    for p in pairs.pairs:  # the first seed's runs in "contacts"; over the seeds, the lags' spread
        runs = [_contact_runs(arm, p.gain, p.collision, SEEDS["B"] + i, model_of(SEEDS["B"] + i), band, kf)
                for i in range(contact_seeds)]  # fmt: skip
        out["contacts"][str(p.gain)] = runs[0]
        out["contact_seeds"][str(p.gain)] = {scen: lag_spread([r[scen] for r in runs]) for scen in runs[0]}
    out["pulses"] = (_pulses(arm, pairs, model_error, pulses, SEEDS["B"] + 1, model_of(SEEDS["B"] + 1), band, kf)
                     if pulses else {})  # fmt: skip
    return out


def run_detection_study(
    arms: Sequence[str | StudyArm] = STUDY_ARMS,
    gains: Sequence[float] = DEFAULT_DETECTION_GAINS,
    *,
    progress: Callable[[str, dict[str, Any]], None] | None = None,
    **kwargs: Any,
) -> DetectionStudy:
    """The study on each arm (names of :data:`~reflexarm.experiments.reaction_study.STUDY_ARMS` or
    :class:`StudyArm`); ``kwargs`` go to :func:`study_arm_detection` (durations, pulses, rate)."""
    from reflexarm.tuning import parse_gains

    g = parse_gains(gains)
    study = DetectionStudy(conditions={"gains_per_s": list(g), "seeds": dict(SEEDS), "model_error": 0.1,
                                       "noise": "paper", "target_lag_s": TARGET_LAG_S, **kwargs})  # fmt: skip
    for a in arms:
        arm = a if isinstance(a, StudyArm) else study_arm(a)
        study.arms[arm.name] = study_arm_detection(arm, g, **kwargs)
        if progress is not None:
            progress(arm.name, study.arms[arm.name])
    return study
