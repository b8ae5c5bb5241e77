"""Figures of a threshold study: the residuals with both proposed levels, and each joint's tail fit."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from reflexarm.tuning.study import ThresholdProposal

__all__ = ["plot_residual_levels", "plot_tails"]

#: At most this many points per joint and log are drawn (min/max per bucket keeps the peaks visible).
_MAX_POINTS = 4000


def _envelope(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per bucket, so a decimated curve keeps its extremes."""
    if t.size <= _MAX_POINTS:
        return t, x
    k = int(np.ceil(t.size / (_MAX_POINTS // 2)))
    m = (t.size // k) * k
    tb, xb = t[:m].reshape(-1, k), x[:m].reshape(-1, k)
    tt = np.repeat(tb[:, 0], 2)
    xx = np.column_stack([xb.min(axis=1), xb.max(axis=1)]).reshape(-1)
    return tt, xx


def plot_residual_levels(proposal: ThresholdProposal, path: str | Path) -> Path:
    """|residual| per joint over the logs (placed end to end) with the contact and collision levels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(proposal.joints)
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.6 * n + 1), sharex=True, squeeze=False)
    for j, ax in enumerate(axes[:, 0]):
        offset = 0.0
        for r in proposal.replays:
            t = r.t - r.t[0] + offset
            tt, xx = _envelope(t, np.abs(r.residual[:, j]))
            ax.plot(tt, xx, lw=0.5, color="0.3")
            offset = t[-1] + r.dt
        jt = proposal.joints[j]
        ax.axhline(jt.contact, color="tab:orange", lw=1.0, ls="--", label=f"contact {jt.contact:.3g} Nm")
        ax.axhline(jt.collision, color="tab:red", lw=1.2, label=f"collision {jt.collision:.3g} Nm")
        ax.set_ylabel(f"|r_{j + 1}| [Nm]\n{jt.name}", fontsize=8)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1, 0].set_xlabel("time in the logs, placed end to end [s]")
    kf = proposal.settings.detection_filter_gain
    stage = "" if kf is None else f", second stage K_f = {kf:g} 1/s"
    fig.suptitle(
        f"free-motion residuals and proposed levels: collision {proposal.rate_per_hour:g}/h, "
        f"contact {proposal.contact_rate_per_hour:g}/h for the arm (k_o = {proposal.settings.detection_gain:g} 1/s"
        f"{stage})",
        fontsize=10,
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_tails(proposal: ThresholdProposal, path: str | Path) -> Path:
    """False alarms per hour against the level, per joint: counted in the logs and the fitted tail."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from reflexarm.tuning.tail import cluster_maxima

    n = len(proposal.joints)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows), squeeze=False)
    per_joint = proposal.rate_per_hour / n
    for j, jt in enumerate(proposal.joints):
        ax = axes[j // cols, j % cols]
        fit = jt.fit
        gap = int(np.ceil(fit.gap_s / proposal.replays[0].dt - 1e-9))
        top = max(fit.x_max, jt.collision_interval[1]) * 1.05
        levels = np.linspace(max(0.0, fit.u - 0.5 * (top - fit.u)), top, 80)
        counted = [
            sum(cluster_maxima(np.abs(r.residual[:, j]), z, gap).size for r in proposal.replays) / fit.duration_h
            for z in levels
        ]
        ax.semilogy(levels, np.maximum(counted, 1e-3), ".", ms=3, color="0.4", label="counted")
        ax.semilogy(levels, [max(fit.rate(z), 1e-3) for z in levels], color="tab:blue", label=f"{fit.method} fit")
        ax.axhline(per_joint, color="tab:red", lw=0.8, ls=":")
        ax.axvline(jt.collision, color="tab:red", lw=1.0, label=f"zeta {jt.collision:.3g}")
        ax.axvspan(*jt.collision_interval, color="tab:red", alpha=0.15)
        ax.set_title(f"joint {j + 1} ({jt.name})", fontsize=8)
        ax.set_xlabel("level [Nm]", fontsize=8)
        ax.set_ylabel("alarms / h (0 at 1e-3)", fontsize=8)
        ax.legend(fontsize=6)
    for k in range(n, rows * cols):
        axes[k // cols, k % cols].axis("off")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
