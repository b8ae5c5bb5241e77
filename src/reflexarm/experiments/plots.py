"""Figures of the collision experiments (Figs. 8 and 10), written as PNG."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reflexarm.sim import Trace  # noqa: E402

__all__ = ["plot_fig8", "plot_fig10"]

_COLORS = {"Stiff": "tab:red", "Compliant": "tab:blue", "Coll.Det": "tab:green"}


def plot_fig8(traces: Sequence[Trace], path: Path, threshold: float = 11.0) -> Path:
    """|f_ext,EE|, residual of joint 1 with the threshold, and q_1 for each run (Fig. 8)."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    for tr in traces:
        name = str(tr.meta["setting"]["name"])
        c = _COLORS.get(name)
        axes[0].plot(tr.t, np.linalg.norm(tr.f_ext_ee, axis=1), color=c, label=name)
        axes[1].plot(tr.t, tr.residual[:, 0], color=c, label=name)
        axes[2].plot(tr.t, tr.q[:, 0], color=c, label=name)
        det = np.flatnonzero(tr.collision)
        if det.size:
            for ax in axes:
                ax.axvline(tr.t[det[0]], color=c, ls=":", lw=1)
    axes[2].plot(traces[0].t, traces[0].q_d[:, 0], color="k", ls="--", lw=1, label="q_d,1")
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
    """q_1, model torque, residual and measured motor torque of one joint during a link collision (Fig. 10)."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    axes[0].plot(trace.t, trace.q[:, joint], label=f"q_{joint + 1}")
    axes[0].plot(trace.t, trace.q_d[:, joint], "k--", lw=1, label=f"q_d,{joint + 1}")
    axes[0].set_ylabel("[rad]")
    axes[1].plot(trace.t, tau_model[:, joint], label=f"tau_mdl,{joint + 1}")
    axes[1].plot(trace.t, trace.residual[:, joint], label=f"residual_{joint + 1}")
    axes[1].plot(trace.t, trace.tau_m[:, joint], label=f"tau_m,{joint + 1}", alpha=0.7)
    for s in (1, -1):
        axes[1].axhline(s * threshold, color="k", ls="--", lw=1)
    det = np.flatnonzero(trace.collision)
    if det.size:
        for ax in axes:
            ax.axvline(trace.t[det[0]], color="tab:green", ls=":", lw=1)
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
