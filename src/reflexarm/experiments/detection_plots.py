"""The detection study's figure: the lag / false-alarm trade-off over the detection gains, the contacts' lags and
their contact-to-detection delays (:mod:`reflexarm.experiments.detection_study`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np

from reflexarm.detect.defaults import DETECTION_LAG_TARGET_S as TARGET_LAG_S


class _Study(Protocol):
    """What the figure reads of a :class:`~reflexarm.experiments.detection_study.DetectionStudy` (not imported:
    the study imports this module to write its figure)."""

    arms: dict[str, dict[str, Any]]

    def rows(self) -> list[dict[str, Any]]: ...

__all__ = ["plot_tradeoff"]


def _ms(value: float | None) -> float:
    return np.nan if value is None else 1e3 * value


def _median_and_max(ax: Any, rows: list[dict[str, Any]], key: str, marker: str, color: Any, label: str) -> None:
    """Over the gains: the median over the noise seeds of ``{key}_median_s`` with a bar up to ``{key}_max_s`` [ms]."""
    gains = [x["gain_per_s"] for x in rows]
    med = [_ms(x.get(f"{key}_median_s")) for x in rows]
    top = [_ms(x.get(f"{key}_max_s")) for x in rows]
    if np.all(np.isnan(med)):  # nothing to draw (e.g. a scenario not run): an empty errorbar breaks a log axis
        return
    ax.errorbar(gains, med, yerr=[np.zeros(len(rows)), np.subtract(top, med)], fmt=marker, ls="-", color=color,
                capsize=2, label=label)  # fmt: skip


def plot_tradeoff(study: _Study, path: str | Path) -> Path:
    """Lag against false alarms per hour over the gains, one line per arm; the contacts' lags over the gains; and
    (with contact runs over noise seeds) their contact-to-detection delays over the gains."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = study.rows()
    seeded = any("demo_delay_median_s" in x for x in rows)
    fig, axes = plt.subplots(1, 3 if seeded else 2, figsize=(18 if seeded else 12, 4.8))
    for name in study.arms:
        r = [x for x in rows if x["arm"] == name]
        fa = [max(x["false_alarms_per_hour"] or 0.0, 0.3) for x in r]  # 0 drawn at 0.3/h (log axis)
        lag = [1e3 * (x["measured_ramp_lag_max_s"] or np.nan) for x in r]
        (line,) = axes[0].plot(lag, fa, "o-", label=name)
        color, gains = line.get_color(), [x["gain_per_s"] for x in r]
        for x, a, b in zip(r, lag, fa, strict=True):
            axes[0].annotate(f"{x['gain_per_s']:g}", (a, b), fontsize=7, textcoords="offset points", xytext=(3, 3))
        for scen, marker in (("demo", "s"), ("link", "^")):
            if seeded:  # over the noise seeds: median, a bar to the max
                _median_and_max(axes[1], r, f"{scen}_joint_lag", marker, color, f"{name} {scen}")
                _median_and_max(axes[2], r, f"{scen}_delay", marker, color, f"{name} {scen}")
            else:
                axes[1].plot(gains, [_ms(x.get(f"{scen}_lag_s")) for x in r], marker, ls="-", color=color,
                             label=f"{name} {scen}")  # fmt: skip
            own = [_ms(x.get(f"{scen}_input_lag_s")) for x in r]
            axes[1].plot(gains, own, marker, ls=":", mfc="none", color=color)
    axes[0].axvline(1e3 * TARGET_LAG_S, color="k", ls="--", lw=0.8)
    axes[0].set(xlabel="detector lag, max over synthetic ramps [ms]", ylabel="false alarms per hour (0 drawn at 0.3)",
                yscale="log", title="lag / false-alarm trade-off over k_o (labels: k_o [1/s])")  # fmt: skip
    axes[1].axhline(1e3 * TARGET_LAG_S, color="k", ls="--", lw=0.8)
    axes[1].set_yscale("symlog", linthresh=10.0)  # lags of a few ms beside detections seconds early or late
    title = ("demo / link: lag after the true |tau_ext_j| exceeds zeta_j (filled: detecting joints,\n"
             "median over the noise seeds, bar to the max) or the observer's input does (open)")
    axes[1].set(xscale="log", xlabel="detection k_o [1/s]", ylabel="lag [ms]")
    axes[1].set_title(title if seeded else "demo / link: lag after the true |tau_ext| exceeds zeta (filled)\n"
                      "or the observer's input does (open)", fontsize=9)  # fmt: skip
    if seeded:
        axes[2].set(xscale="log", yscale="log", xlabel="detection k_o [1/s]", ylabel="contact to detection [ms]")
        axes[2].set_title("demo / link: contact-to-detection delay\n(median over the noise seeds, bar to the max)",
                          fontsize=9)  # fmt: skip
        axes[2].legend(fontsize=6, ncol=2)
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=6, ncol=2)
    detector = _detector_text(study)
    if detector:
        fig.suptitle(detector, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def _detector_text(study: _Study) -> str:
    """What the detector ran beyond the paper's first order (the same on every arm, else per arm), or ""."""
    from reflexarm.tuning.replay import detector_words

    words = {name: detector_words(a.get("detection_friction_band"), a.get("detection_filter_gain"))
             for name, a in study.arms.items()}  # fmt: skip
    parts = {name: f"detection observer{w}" if w else "" for name, w in words.items()}
    texts = set(parts.values())
    if texts == {""}:
        return ""
    if len(texts) == 1:
        return texts.pop()
    return "; ".join(f"{name}: {t or 'first order'}" for name, t in parts.items())
