"""Figures of the experiments, written as PNG: collisions (Figs. 8, 10), compensation (Figs. 11-14).

The compensation figures are built by ``*_figure`` functions returning a :class:`matplotlib.figure.Figure`
(no pyplot state; its lines and labels can be inspected) and written by the ``plot_*`` functions.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from reflexarm.experiments.compensation import CASES, ee_positions  # noqa: E402
from reflexarm.sim import Trace  # noqa: E402

if TYPE_CHECKING:
    from reflexarm.experiments.compliance_loss import ComplianceLossResult, ComplianceSweepResult
    from reflexarm.experiments.efc_step import EfcStepResult

__all__ = [
    "compliance_loss_figure",
    "compliance_sweep_figure",
    "crossover_levels",
    "efc_step_figure",
    "free_motion_figure",
    "guard_verdict",
    "mode_table_figure",
    "phase_spans",
    "plot_compliance_loss",
    "plot_compliance_sweep",
    "plot_efc_step",
    "plot_fig8",
    "plot_fig10",
    "plot_free_motion",
    "plot_mode_table",
    "plot_sweep",
    "sweep_figure",
]

_COLORS = {"Stiff": "tab:red", "Compliant": "tab:blue", "Coll.Det": "tab:green"}

#: Shading of the reaction's phases after detection (the trace's ``mode``), one colour per mode.
_PHASE_COLORS = {
    "gravity_compensation": "tab:olive",
    "braking": "tab:orange",
    "retracting": "tab:purple",
    "holding": "tab:cyan",
    "compliant": "tab:gray",
    "fault": "tab:red",
}


def phase_spans(trace: Trace) -> list[tuple[str, float, float]]:
    """The reaction's phases: (mode, start, end) [s] of each run of equal ``trace.mode`` from the first
    detection on (empty without a detection); each span ends where the next begins (the last at the end)."""
    det = np.flatnonzero(trace.collision)
    if det.size == 0:
        return []
    k0 = int(det[0])
    mode = trace.mode[k0:]
    starts = np.flatnonzero(np.r_[True, mode[1:] != mode[:-1]]) + k0
    ends = [*trace.t[starts[1:]].tolist(), float(trace.t[-1])]
    return [(str(trace.mode[k]), float(trace.t[k]), e) for k, e in zip(starts, ends, strict=True)]


def guard_verdict(trace: Trace) -> str:
    """One line on what the reaction left the arm doing, from the controller's event record: the guard's
    report, "at rest" when the guard checked and found nothing, else why there is no verdict."""
    event = trace.meta.get("collision_event")
    if not isinstance(event, dict):
        return "no detection"
    head = f"{event.get('reaction', '?')} ({event.get('contact_class', '?')})"
    if event.get("text"):
        return f"{head}: {event['text']}"
    if event.get("guard_checked"):
        return f"{head}: the arm came to rest"
    return f"{head}: not checked yet (the run ended before the guard's window)"


def _mark_event(axes: Sequence[Any], trace: Trace, color: str | None, name: str, shaded: set[str]) -> str | None:
    """Detection (dotted line) and the reaction's phases (shaded spans, one legend entry per mode) of one run;
    returns the line of its guard's verdict (None without a detection)."""
    det = np.flatnonzero(trace.collision)
    if det.size == 0:
        return None
    t_det = float(trace.t[det[0]])
    for ax in axes:
        ax.axvline(t_det, color=color, ls=":", lw=1)
    for mode, t0, t1 in phase_spans(trace):
        label = None if mode in shaded else f"phase: {mode}"
        shaded.add(mode)
        for i, ax in enumerate(axes):
            ax.axvspan(t0, t1, color=_PHASE_COLORS.get(mode, "0.8"), alpha=0.12, lw=0, label=label if i == 0 else None)
    return f"{name}: detected {t_det:.3f} s; {guard_verdict(trace)}"


def _verdicts(ax: Any, lines: Sequence[str]) -> None:
    """The guards' verdicts in a box in the upper right of ``ax``."""
    if lines:
        ax.text(
            0.99,
            0.97,
            "\n".join(textwrap.fill(x, 70) for x in lines),
            transform=ax.transAxes,
            ha="right",
            va="top",
            fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"},
        )


def plot_fig8(traces: Sequence[Trace], path: Path, threshold: float = 11.0) -> Path:
    """|f_ext,EE|, residual of joint 1 with the threshold, and q_1 for each run (Fig. 8); for a run with a
    detection its time (dotted), the reaction's phases from the trace's mode (shaded) and the guard's verdict
    (box in the q_1 panel)."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    shaded: set[str] = set()
    verdicts: list[str] = []
    for tr in traces:
        name = str(tr.meta["setting"]["name"])
        c = _COLORS.get(name)
        axes[0].plot(tr.t, np.linalg.norm(tr.f_ext_ee, axis=1), color=c, label=name)
        axes[1].plot(tr.t, tr.residual[:, 0], color=c, label=name)
        axes[2].plot(tr.t, tr.q[:, 0], color=c, label=name)
        verdict = _mark_event(axes, tr, c, name, shaded)
        if verdict:
            verdicts.append(verdict)
    axes[2].plot(traces[0].t, traces[0].q_d[:, 0], color="k", ls="--", lw=1, label="q_d,1")
    _verdicts(axes[2], verdicts)
    for s in (1, -1):
        axes[1].axhline(s * threshold, color="k", ls="--", lw=1)
    axes[0].set_ylabel("|f_ext,EE| [N]")
    axes[1].set_ylabel("residual joint 1 [Nm]")
    axes[2].set_ylabel("q_1 [rad]")
    axes[2].set_xlabel("t [s]")
    axes[0].legend(loc="upper left")
    axes[2].legend(loc="lower left", fontsize=8)
    axes[0].set_title("End-effector collision with a padded cinderblock (cf. Fig. 8)")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_fig10(trace: Trace, tau_model: np.ndarray, path: Path, threshold: float = 11.0, joint: int = 0) -> Path:
    """q_1, model torque, residual and measured motor torque of one joint during a link collision (Fig. 10),
    with the detection, the reaction's phases and the guard's verdict marked as in :func:`plot_fig8`."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    axes[0].plot(trace.t, trace.q[:, joint], label=f"q_{joint + 1}")
    axes[0].plot(trace.t, trace.q_d[:, joint], "k--", lw=1, label=f"q_d,{joint + 1}")
    axes[0].set_ylabel("[rad]")
    axes[1].plot(trace.t, tau_model[:, joint], label=f"tau_mdl,{joint + 1}")
    axes[1].plot(trace.t, trace.residual[:, joint], label=f"residual_{joint + 1}")
    axes[1].plot(trace.t, trace.tau_m[:, joint], label=f"tau_m,{joint + 1}", alpha=0.7)
    for s in (1, -1):
        axes[1].axhline(s * threshold, color="k", ls="--", lw=1)
    verdict = _mark_event(axes, trace, "tab:green", "Coll.Det", set())
    _verdicts(axes[1], [verdict] if verdict else [])
    axes[1].set_ylabel("[Nm]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title("Link collision at the elbow (cf. Fig. 10)")
    for ax in axes:
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------- compensation
def _figure(rows: int, cols: int, size: tuple[float, float], sharex: bool = True) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    fig.subplots(rows, cols, sharex=sharex)
    return fig


def _save(fig: Figure, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=120)
    return p


def efc_step_figure(result: EfcStepResult) -> Figure:
    """Fig. 12: q_j, tau_ext,j and the residual tau_eps_hat,j of the three runs, j the loaded joint
    (``result.joint``: joint 1 on the Atlas arm, as in the paper)."""
    fig = _figure(3, 1, (7.0, 7.5))
    axes = fig.axes
    colors = {"no DC": "C0", "DC": "C3", "DC+EFC": "C2", "DC, no cut-off": "0.6"}
    labels = {
        "no DC": "DC off ($\\kappa_\\varepsilon=0$)",
        "DC": "DC, no EFC ($\\kappa_{ext}=0$)",
        "DC+EFC": "DC + EFC ($\\kappa_{ext}=1$)",
    }
    for name in CASES:
        tr = result.traces[name]
        kw: dict[str, Any] = {"color": colors[name], "lw": 1.2, "label": labels[name]}
        axes[0].plot(tr.t, tr.q[:, result.joint], **kw)
        axes[1].plot(tr.t, tr.tau_ext[:, result.joint], **kw)
        axes[2].plot(tr.t, tr.residual[:, result.joint], **kw)
    j = result.joint + 1
    axes[0].set_ylabel(f"$q_{{{j}}}$ [rad] (loaded joint)")
    axes[1].set_ylabel(f"$\\tau_{{ext,{j}}}$ [Nm]")
    axes[2].set_ylabel(f"$\\hat{{\\tau}}_{{\\varepsilon,{j}}}$ [Nm]")
    axes[2].set_xlabel("t [s]")
    axes[0].legend(loc="best", fontsize=8)
    s = result.setup
    axes[0].set_title(
        f"{s.force:g} N step on the end effector, {s.t_on:g}-{s.t_off:g} s; k={s.stiffness:g}, "
        f"$k_o$={s.observer_gain:g}, ±{100 * s.model_error:g} % model errors, noise x{s.noise_scale:g}",
        fontsize=9,
    )
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.axvspan(s.t_on, s.t_off, color="0.9", zorder=-1)
    return fig


def plot_efc_step(result: EfcStepResult, path: str | Path) -> Path:
    """:func:`efc_step_figure` written to ``path`` (PNG)."""
    return _save(efc_step_figure(result), path)


def compliance_loss_figure(result: ComplianceLossResult) -> Figure:
    """Fig. 11: displacement along the push and the hand's force, with and without DC."""
    fig = _figure(3, 1, (7.0, 7.5))
    ax_x, ax_f, ax_r = fig.axes
    colors = {"no DC": "C0", "DC": "C3", "DC, no cut-off": "0.5"}
    for name, tr in result.traces.items():
        P = ee_positions(tr)
        f = tr.extras["hand_force"]
        u = f[np.argmax(np.linalg.norm(f, axis=1))]
        u = u / max(np.linalg.norm(u), 1e-12)
        ax_x.plot(tr.t, 1000 * (P - P[0]) @ u, color=colors[name], label=name)
        ax_f.plot(tr.t, np.linalg.norm(f, axis=1), color=colors[name], label=name)
        ax_r.plot(tr.t, tr.residual[:, 0], color=colors[name], label=name)
    ax_r.axhline(30.0, color="k", ls=":", lw=0.8)
    ax_r.axhline(-30.0, color="k", ls=":", lw=0.8)
    ax_x.set_ylabel("$\\Delta x$ along push [mm]")
    ax_f.set_ylabel("$|f|$ [N]")
    ax_r.set_ylabel("$\\hat{\\tau}_{\\varepsilon,1}$ [Nm]")
    ax_r.set_xlabel("t [s]")
    ax_x.legend(fontsize=8)
    s = result.summary
    ax_x.set_title(
        f"push and hold: force x{s['force_ratio']:.2f}, displacement x{s['displacement_ratio']:.2f}, "
        f"stiffness x{s['stiffness_ratio']:.2f} with DC (no cut-off: x{s['stiffness_ratio_no_cutoff']:.1f})",
        fontsize=9,
    )
    for ax in fig.axes:
        ax.grid(alpha=0.3)
    return fig


def plot_compliance_loss(result: ComplianceLossResult, path: str | Path) -> Path:
    """:func:`compliance_loss_figure` written to ``path`` (PNG)."""
    return _save(compliance_loss_figure(result), path)


#: Paper's Fig. 11 ratios, DC / no DC (force, displacement, apparent stiffness).
_PAPER_FIG11 = {"force_ratio": 1.93, "displacement_ratio": 0.67, "stiffness_ratio": 1.93 / 0.67}


def compliance_sweep_figure(result: ComplianceSweepResult) -> Figure:
    """Fig. 11 over the hand's stiffness: the three ratios DC / no DC against the paper's (dashed)."""
    fig = _figure(1, 1, (6.5, 4.2))
    ax = fig.axes[0]
    rows = result.rows()
    k = [r["hand_stiffness_N_per_m"] for r in rows]
    names = {"force_ratio": "force", "displacement_ratio": "displacement", "stiffness_ratio": "stiffness |f|/dx"}
    for i, (key, label) in enumerate(names.items()):
        ax.plot(k, [r[key] for r in rows], "o-", color=f"C{i}", label=f"{label} (ours)")
        ax.axhline(_PAPER_FIG11[key], color=f"C{i}", ls="--", lw=1, label=f"{label} (paper {_PAPER_FIG11[key]:.2f})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("hand stiffness [N/m]")
    ax.set_ylabel("ratio DC / no DC [-]")
    ax.set_title("Fig. 11: push and hold, with DC / without, over the pushing hand's stiffness", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3, which="both")
    return fig


def plot_compliance_sweep(result: ComplianceSweepResult, path: str | Path) -> Path:
    """:func:`compliance_sweep_figure` written to ``path`` (PNG)."""
    return _save(compliance_sweep_figure(result), path)


#: kappa_ext of the sweep conditions (Figs. 13-14).
_KAPPA_EXT = {"DC": 0, "DC+EFC": 1}
_COND_COLOR = {"DC": "C3", "DC+EFC": "C2"}
_LEVEL_UNITS = {"model-error": "max. model error [%]", "noise": "noise scale factor [-]"}


def _by_condition(summary: pd.DataFrame) -> dict[str, pd.DataFrame]:
    return {
        c: summary[summary["condition"] == c].sort_values("level") for c in _KAPPA_EXT if c in set(summary["condition"])
    }


def crossover_levels(summary: pd.DataFrame) -> list[float]:
    """Levels at which the mean MSIE of DC (no EFC) is below DC+EFC's (Fig. 14's crossover)."""
    w = summary.pivot(index="level", columns="condition", values="msie_mean")
    if not {"DC", "DC+EFC"} <= set(w.columns):
        return []
    return [float(lv) for lv in w.index[w["DC"] < w["DC+EFC"]]]


def sweep_figure(summary: pd.DataFrame, kind: str, residual_limit: float = 30.0) -> Figure:
    """Figs. 13/14: both controllers in one panel (normalised MSIE, log scale), and what explains them.

    Top: ``||MSIE||`` over the level for DC (kappa_ext = 0) and DC+EFC (kappa_ext = 1), mean and min-max
    over the trials; a crossover (DC below DC+EFC) is marked. Below, for ``model-error``: the MSIE's
    increase over the lowest level for both (the model errors' own share) and the achieved relative
    error of g(q) and M(q); for ``noise``: joint 1's residual under the load (noise measured and predicted,
    the mean compensated residual of DC, the external torque) against the cut-off.
    """
    fig = _figure(3 if kind == "model-error" else 2, 1, (6.5, 8.5 if kind == "model-error" else 6.5))
    axes = fig.axes
    by = _by_condition(summary)
    for cond, s in by.items():
        c = _COND_COLOR[cond]
        label = f"{cond} ($\\kappa_{{ext}}={_KAPPA_EXT[cond]}$)"
        axes[0].fill_between(s["level"], s["norm_min"], s["norm_max"], color=c, alpha=0.2, lw=0)
        axes[0].plot(s["level"], s["norm_mean"], "o-", color=c, ms=3, label=label)
    axes[0].set_yscale("log")
    axes[0].set_ylabel("||MSIE|| [-]")
    cross = crossover_levels(summary)
    if cross:
        axes[0].axvline(cross[0], color="k", ls=":", lw=1, label=f"crossover at {cross[0]:g}")
    axes[0].set_title(
        ("Fig. 13: model errors" if kind == "model-error" else "Fig. 14: sensor noise")
        + (f"; DC below DC+EFC from {cross[0]:g}" if cross else "; no crossover at the levels run"),
        fontsize=10,
    )
    axes[0].legend(fontsize=8)
    if kind == "model-error":
        for cond, s in by.items():
            base = float(s["msie_mean"].iloc[0])
            axes[1].plot(s["level"], s["msie_mean"] - base, "o-", color=_COND_COLOR[cond], ms=3, label=cond)
        axes[1].set_ylabel(f"MSIE - MSIE(level {float(summary['level'].min()):g}) [rad$^2$]")
        axes[1].legend(fontsize=8)
        s = next(iter(by.values()))
        if "g_error_median" in s:
            axes[2].plot(s["level"], 100 * s["g_error_median"], "o-", color="C0", ms=3, label="g(q), median")
            axes[2].plot(s["level"], 100 * s["M_error_median"], "s-", color="C1", ms=3, label="M(q), median")
        axes[2].set_ylabel("achieved model error [%]")
        axes[2].legend(fontsize=8)
    else:
        for cond, s in by.items():
            c = _COND_COLOR[cond]
            if "residual1_load_std_Nm" in s:
                axes[1].plot(s["level"], s["residual1_load_std_Nm"], "o-", color=c, ms=3, label=f"std res$_1$, {cond}")
            if cond == "DC" and "compensated1_load_Nm" in s:
                axes[1].plot(
                    s["level"], s["compensated1_load_Nm"], "s-", color="C4", ms=3, label="mean cut-off res$_1$, DC"
                )
                axes[1].plot(s["level"], s["tau_ext1_load_Nm"], color="0.4", lw=1, label="$\\tau_{ext,1}$")
                axes[1].plot(s["level"], s["residual1_noise_pred_Nm"], "k--", lw=1, label="predicted std (dq noise)")
        axes[1].axhline(residual_limit, color="k", ls=":", lw=1, label=f"cut-off {residual_limit:g} Nm")
        axes[1].set_ylabel("joint 1 under load [Nm]")
        axes[1].legend(fontsize=7)
    axes[-1].set_xlabel(_LEVEL_UNITS.get(kind, "level"))
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    return fig


def plot_sweep(summary: pd.DataFrame, kind: str, path: str | Path, residual_limit: float = 30.0) -> Path:
    """:func:`sweep_figure` written to ``path`` (PNG)."""
    return _save(sweep_figure(summary, kind, residual_limit), path)


# ------------------------------------------------------------------------------- free motion, mode table
def free_motion_figure(
    result: dict[str, Any], joint_names: Sequence[str], threshold: float, trace_path: str | Path | None = None
) -> Figure:
    """The false-alarm check: largest |residual| per joint against zeta and, from the streamed trace (if
    any), the envelope of |residual| per joint over time (max per 0.1 s, read block by block)."""
    fig = _figure(2 if trace_path else 1, 1, (8.0, 6.0 if trace_path else 3.5), sharex=False)
    axes = fig.axes
    peak = np.asarray(result["max_abs_residual_Nm"], dtype=float)
    labels = [f"{j + 1} {name}" for j, name in enumerate(joint_names)]
    axes[0].bar(labels, peak, color=["C3" if p >= threshold else "C0" for p in peak])
    axes[0].axhline(threshold, color="k", ls="--", lw=1, label=f"threshold zeta = {threshold:g} Nm")
    axes[0].set_ylabel("max |residual| [Nm]")
    axes[0].set_xlabel("joint")
    axes[0].legend(fontsize=8)
    axes[0].set_title(
        f"Free motion, {float(result['duration_s']):.1f} s: {result['false_alarm_events']} false alarm(s)", fontsize=9
    )
    if trace_path:
        t_env, env = _residual_envelope(trace_path, 0.1)
        for j, label in enumerate(labels):
            axes[1].plot(t_env, env[:, j], lw=0.8, label=label)
        axes[1].axhline(threshold, color="k", ls="--", lw=1)
        axes[1].set_ylabel("|residual|, max per 0.1 s [Nm]")
        axes[1].set_xlabel("t [s]")
        axes[1].legend(fontsize=7, ncol=min(len(labels), 4))
    return fig


def _residual_envelope(trace_path: str | Path, bin_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(bin start times, max |residual| per bin and joint) of a streamed Parquet trace, block by block."""
    times: list[np.ndarray] = []
    peaks: list[np.ndarray] = []
    for block in Trace.iter_blocks(trace_path):
        key = np.floor(block.t / bin_s).astype(np.int64)
        starts = np.flatnonzero(np.r_[True, np.diff(key) != 0])
        times.append(key[starts] * bin_s)
        peaks.append(np.maximum.reduceat(np.abs(block.residual), starts, axis=0))
    if not times:
        return np.zeros(0), np.zeros((0, 0))
    return np.concatenate(times), np.vstack(peaks)


def plot_free_motion(
    result: dict[str, Any],
    joint_names: Sequence[str],
    threshold: float,
    path: str | Path,
    trace_path: str | Path | None = None,
) -> Path:
    """Write :func:`free_motion_figure` as PNG."""
    return _save(free_motion_figure(result, joint_names, threshold, trace_path), path)


def mode_table_figure(rows: Sequence[dict[str, Any]], check_ratio: float) -> Figure:
    """Fig. 3 measured: per mode, the accuracy ratio and the compliance ratios against the check mark's
    bound (accurate: ratio <= bound; compliant: ratio >= bound)."""
    fig = _figure(1, 1, (8.0, 3.8))
    ax = fig.axes[0]
    keys = [
        ("accuracy_ratio", "accuracy: RMS error / compliant's"),
        ("ee_compliance_ratio", "EE compliance"),
        ("link_compliance_ratio", "link compliance"),
        ("link_compliance_supervised_ratio", "link, auto-switch"),
    ]
    x = np.arange(len(rows))
    width = 0.8 / len(keys)
    for i, (key, label) in enumerate(keys):
        ax.bar(x + (i - (len(keys) - 1) / 2) * width, [float(r[key]) for r in rows], width, label=label)
    ax.axhline(check_ratio, color="k", ls="--", lw=1, label=f"check-mark bound {check_ratio:g}")
    ax.set_xticks(x, [str(r["mode"]) for r in rows], fontsize=8)
    ax.set_ylabel("ratio [-]")
    ax.legend(fontsize=7)
    ax.set_title("Fig. 3 measured: accuracy and compliance of each control mode", fontsize=9)
    return fig


def plot_mode_table(rows: Sequence[dict[str, Any]], check_ratio: float, path: str | Path) -> Path:
    """Write :func:`mode_table_figure` as PNG."""
    return _save(mode_table_figure(rows, check_ratio), path)
