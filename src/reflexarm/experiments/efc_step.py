"""Fig. 12: a 50 N step on the end effector with DC off, DC without EFC, DC with EFC (Sec. III-C-2).

The effect is measured on the joint that carries the load: the one with the largest mean |tau_ext| under
the load (:func:`loaded_joint`). On the Atlas arm in its home posture that is joint 1, the joint the paper
plots; on other arms it is not (on a Gen3-like arm joint 1 carries nothing, and its residual is noise).
The rows keep joint 1's numbers too (``q1_displacement_rad``, ``tau_ext1_Nm``, ``residual1_Nm``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from reflexarm.experiments.compensation import (
    CASES,
    NO_CUTOFF,
    CompensationSetup,
    ee_positions,
    run_case,
    true_robot,
)
from reflexarm.experiments.metrics import window_mean
from reflexarm.experiments.sweeps import trial_seeds
from reflexarm.robots import RobotModel
from reflexarm.sim import Trace

__all__ = ["EfcStepResult", "efc_step"]


@dataclass
class EfcStepResult:
    """What :func:`efc_step` returns: traces by case, the table rows and the headline ratios."""

    traces: dict[str, Trace]
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    setup: CompensationSetup = field(default_factory=CompensationSetup)
    joint: int = 0  # the loaded joint (0-based), see loaded_joint


def loaded_joint(trace: Trace, setup: CompensationSetup) -> tuple[int, np.ndarray]:
    """The joint carrying the load (0-based: largest |mean tau_ext| over the load window) and the mean
    tau_ext per joint [Nm]."""
    tau = np.asarray(window_mean(trace.t, trace.tau_ext, *setup.load_window))
    return int(np.argmax(np.abs(tau))), tau


def _step_row(name: str, trace: Trace, setup: CompensationSetup, robot: RobotModel, joint: int) -> dict[str, Any]:
    t = trace.t
    P = ee_positions(trace, robot)
    pre, load = setup.pre_window, setup.load_window
    dx = window_mean(t, P, *load) - window_mean(t, P, *pre)
    dq = window_mean(t, trace.q, *load) - window_mean(t, trace.q, *pre)
    r = window_mean(t, trace.residual, *load)
    after = (setup.t_off + 1.0, setup.duration)
    row = {
        "run": name,
        "kappa_eps": trace.meta["kappa_eps"],
        "kappa_ext": trace.meta["kappa_ext"],
        "residual_limit_Nm": trace.meta["residual_limit"],
        "ee_displacement_mm": 1000 * float(np.linalg.norm(dx)),
        "loaded_joint": joint + 1,
        "q_loaded_displacement_rad": float(dq[joint]),
        "tau_ext_loaded_Nm": float(window_mean(t, trace.tau_ext[:, joint], *load)),
        "residual_loaded_Nm": float(r[joint]),
        "q1_displacement_rad": float(dq[0]),
        "tau_ext1_Nm": float(window_mean(t, trace.tau_ext[:, 0], *load)),
        "residual1_Nm": float(r[0]),
        "residual_norm_Nm": float(np.linalg.norm(r)),
        "max_abs_residual_Nm": float(np.abs(trace.residual).max()),
        "q_displacement_rad": [float(x) for x in dq],
    }
    if after[1] > after[0]:
        row["ee_after_release_mm"] = 1000 * float(np.linalg.norm(window_mean(t, P, *after) - window_mean(t, P, *pre)))
    return row


def efc_step(
    setup: CompensationSetup | None = None, *, seed: int = 0, model_seed: int | None = None, progress: bool = False
) -> EfcStepResult:
    """Fig. 12: the 50 N step with no DC, DC without EFC, DC with EFC; plus DC without the 30 Nm cut-off.

    All runs share the model-error draw and the noise sequence (``seed``). Steady state under the load
    is the mean over :attr:`CompensationSetup.load_window`, measured from the mean over
    :attr:`CompensationSetup.pre_window`.

    Summary ratios:
        ``efc_vs_nodc_displacement``: EE displacement with EFC / without DC (paper: ~1);
        ``dc_vs_nodc_displacement``: DC without EFC / without DC (paper: ~0, "very stiff");
        ``loaded_joint`` (1-based, :func:`loaded_joint`) and ``loaded_joint_name``;
        ``efc_vs_dc_residual_loaded``, ``efc_vs_dc_residual_norm``: |residual| under load, EFC / DC, on the
        loaded joint and the norm over all joints (paper: near zero); ``efc_vs_dc_residual1`` on joint 1;
        ``efc_vs_nodc_q_loaded`` (``efc_vs_nodc_q1``): the loaded joint's (joint 1's) displacement, EFC / no DC;
        ``cutoff_share_of_dc_displacement``: the part of the DC displacement that the 30 Nm cut-off
        explains, ``(d_DC - d_DC,no cut-off) / d_DC``; ``peak_dc_residual_Nm`` tells whether it was hit.
    """
    setup = setup or CompensationSetup()
    robot = true_robot(setup)
    derived_seed, noise_seed = trial_seeds(seed, 0)
    model_seed = derived_seed if model_seed is None else model_seed
    runs: dict[str, tuple[int, int, float | None]] = {name: (ke, kx, None) for name, (ke, kx) in CASES.items()}
    runs["DC, no cut-off"] = (1, 0, NO_CUTOFF)
    traces: dict[str, Trace] = {}
    for name, (ke, kx, limit) in runs.items():
        traces[name] = run_case(
            setup, ke, kx, model_seed=model_seed, noise_seed=noise_seed, residual_limit=limit, progress=progress
        )
    joint, tau_ext = loaded_joint(traces["no DC"], setup)  # the load is the same step in every run
    rows = [_step_row(name, tr, setup, robot, joint) for name, tr in traces.items()]
    by = {r["run"]: r for r in rows}
    d_no, d_dc, d_efc, d_inf = (by[k]["ee_displacement_mm"] for k in ("no DC", "DC", "DC+EFC", "DC, no cut-off"))
    summary = {
        "efc_vs_nodc_displacement": d_efc / d_no,
        "dc_vs_nodc_displacement": d_dc / d_no,
        "loaded_joint": joint + 1,
        "loaded_joint_name": robot.joint_names[joint],
        "tau_ext_Nm": [float(x) for x in tau_ext],
        "efc_vs_dc_residual_loaded": abs(by["DC+EFC"]["residual_loaded_Nm"]) / abs(by["DC"]["residual_loaded_Nm"]),
        "efc_vs_nodc_q_loaded": by["DC+EFC"]["q_loaded_displacement_rad"] / by["no DC"]["q_loaded_displacement_rad"],
        "efc_vs_dc_residual1": abs(by["DC+EFC"]["residual1_Nm"]) / abs(by["DC"]["residual1_Nm"]),
        "efc_vs_dc_residual_norm": by["DC+EFC"]["residual_norm_Nm"] / by["DC"]["residual_norm_Nm"],
        "efc_vs_nodc_q1": by["DC+EFC"]["q1_displacement_rad"] / by["no DC"]["q1_displacement_rad"],
        "cutoff_share_of_dc_displacement": (d_dc - d_inf) / d_dc if d_dc > 0 else 0.0,
        "peak_dc_residual_Nm": by["DC"]["max_abs_residual_Nm"],
        "model_seed": model_seed,
        "noise_seed": noise_seed,
    }
    return EfcStepResult(traces, rows, summary, setup, joint)
