"""The figure of one log's detection: per joint the residual, its level +-zeta, the events and the glitches."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from reflexarm.detect.result import LogDetection

__all__ = ["plot_detection"]


def plot_detection(d: LogDetection, path: str | Path) -> Path:
    """Write ``path`` (PNG): one panel per joint, residual [Nm] against time [s], +-zeta dashed, each event a red
    line at its detection (its isolated link named in the top panel), each repaired glitch a grey cross."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = d.residual.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.3 * n + 1.2), sharex=True, squeeze=False)
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(d.t, d.residual[:, j], lw=0.6, color="C0")
        for z in (d.zeta[j], -d.zeta[j]):
            ax.axhline(z, color="C1", ls="--", lw=0.8)
        for e in d.events:
            ax.axvline(e.t_detect, color="C3", lw=0.8, alpha=0.7)
        marks = [g for g in d.glitches if g.joint == j]
        if marks:
            ks = np.array([g.sample for g in marks])
            ax.plot(d.t[ks], d.residual[ks, j], "x", color="0.4", ms=5)
        ax.set_ylabel(f"r{j + 1} [Nm]", fontsize=8)
        ax.tick_params(labelsize=7)
    top = axes[0, 0]
    for e in d.events:
        link = "?" if e.estimate is None or e.estimate.link < 0 else str(e.estimate.link + 1)
        top.annotate(f"L{link}", (e.t_detect, d.zeta[0]), fontsize=6, color="C3", xytext=(1, 2),
                     textcoords="offset points")  # fmt: skip
    axes[-1, 0].set_xlabel("t [s]")
    k_o = d.settings.detection_gain
    fig.suptitle(
        f"{d.source}: detection residual (k_o = {k_o:g} 1/s, exact, {d.rate_hz:.4g} Hz), +-zeta dashed, "
        f"{len(d.events)} event(s) in red, {len(d.glitches)} repaired glitch(es) x",
        fontsize=9,
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
