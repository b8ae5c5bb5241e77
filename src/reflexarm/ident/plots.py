"""Figures of the identification: friction characteristics (Fig. 4), measured vs model torques (Fig. 6),
the excitation trajectory. ``<name>_figure`` builds the matplotlib figure (for inspection or further
drawing), ``plot_<name>`` writes it as PNG and closes it."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reflexarm.ident.estimation.identify import TorqueValidation  # noqa: E402
from reflexarm.ident.excitation.design import ExcitationDesign  # noqa: E402
from reflexarm.ident.friction.joint_friction import FrictionFit  # noqa: E402

__all__ = [
    "excitation_figure",
    "friction_figure",
    "plot_excitation",
    "plot_friction",
    "plot_torque_validation",
    "torque_validation_figure",
]


def _save(fig: plt.Figure, path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(p, dpi=120)
    plt.close(fig)
    return p


def plot_friction(
    fits: Sequence[FrictionFit],
    path: str | os.PathLike[str],
    *,
    joint_names: Sequence[str] | None = None,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Write :func:`friction_figure` to ``path`` (PNG)."""
    return _save(friction_figure(fits, joint_names=joint_names, truth=truth), path)


def friction_figure(
    fits: Sequence[FrictionFit],
    *,
    joint_names: Sequence[str] | None = None,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> plt.Figure:
    """Friction torque against velocity, one panel per joint (cf. Fig. 4).

    Markers: the mean of one constant-velocity interval; line: the fitted Coulomb + viscous law;
    dashed: the true law ``(mu_C, d_v)`` if ``truth`` is given (simulation).
    """
    k = len(fits)
    cols = min(k, 4)
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    for ax, f in zip(axes.flat, fits, strict=False):
        v = np.array([p.velocity for p in f.points])
        tau = np.array([p.torque for p in f.points])
        if f.offset is not None:
            tau = tau - f.offset
        vmax = max(np.abs(v).max() * 1.1, 1e-3)
        grid = np.linspace(-vmax, vmax, 401)
        grid = grid[grid != 0]
        ax.plot(v, tau, "o", color="tab:blue", ms=5, label="constant-velocity runs")
        ax.plot(
            grid,
            f.viscous * grid + f.coulomb * np.sign(grid),
            color="tab:blue",
            lw=1.5,
            label=f"fit: mu_C {f.coulomb:.2f} Nm, d_v {f.viscous:.2f} Nms/rad",
        )
        if truth is not None:
            mu, dv = truth[0][f.joint], truth[1][f.joint]
            ax.plot(grid, dv * grid + mu * np.sign(grid), "k--", lw=1, label=f"true: {mu:.2f}, {dv:.2f}")
        name = joint_names[f.joint] if joint_names is not None else ""
        ax.set_title(f"joint {f.joint + 1} {name}".strip())
        ax.set_xlabel("dq [rad/s]")
        ax.set_ylabel("tau_f [Nm]" + (" (offset removed)" if f.offset is not None else ""))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    for ax in list(axes.flat)[k:]:
        ax.set_visible(False)
    fig.suptitle("Single-joint friction identification (cf. Fig. 4)")
    return fig


def plot_torque_validation(
    validations: Mapping[str, TorqueValidation],
    path: str | os.PathLike[str],
    *,
    joint_names: Sequence[str] | None = None,
    joints: Sequence[int] | None = None,
    window: tuple[float, float] | None = None,
) -> Path:
    """Write :func:`torque_validation_figure` to ``path`` (PNG)."""
    return _save(torque_validation_figure(validations, joint_names=joint_names, joints=joints, window=window), path)


def torque_validation_figure(
    validations: Mapping[str, TorqueValidation],
    *,
    joint_names: Sequence[str] | None = None,
    joints: Sequence[int] | None = None,
    window: tuple[float, float] | None = None,
) -> plt.Figure:
    """Measured and model torques per joint on a validation trajectory (cf. Fig. 6), one panel per joint;
    each model's legend entry carries its validation MSE on that joint."""
    first = next(iter(validations.values()))
    n = first.measured.shape[1]
    idx = list(range(n)) if joints is None else list(joints)
    t = first.t
    sel = np.ones(t.size, dtype=bool) if window is None else (t >= window[0]) & (t <= window[1])
    fig, axes = plt.subplots(len(idx), 1, figsize=(9, 1.9 * len(idx)), sharex=True, squeeze=False)
    colors = ["tab:red", "tab:blue", "tab:green", "tab:orange"]
    for row, j in enumerate(idx):
        ax = axes[row, 0]
        ax.plot(t[sel], first.measured[sel, j], color="0.3", lw=0.8, label="tau_m measured")
        for c, (label, v) in zip(colors, validations.items(), strict=False):
            ax.plot(v.t[sel], v.predicted[sel, j], color=c, lw=1.0, label=f"{label} (MSE {v.mse[j]:.3g})")
        name = joint_names[j] if joint_names is not None else ""
        ax.set_ylabel(f"{j + 1} {name}\n[Nm]", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right", ncol=len(validations) + 1)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("Measured and model torques on the validation trajectory (cf. Fig. 6)")
    return fig


def plot_excitation(
    design: ExcitationDesign, path: str | os.PathLike[str], *, joint_names: Sequence[str] | None = None
) -> Path:
    """Write :func:`excitation_figure` to ``path`` (PNG)."""
    return _save(excitation_figure(design, joint_names=joint_names), path)


def excitation_figure(design: ExcitationDesign, *, joint_names: Sequence[str] | None = None) -> plt.Figure:
    """q, dq, ddq of the initial (dotted) and the optimized (solid) excitation over one period, with the
    velocity and acceleration bounds (dashed)."""
    tr, tr0 = design.trajectory, design.initial
    t = np.linspace(0.0, tr.period, 1000)
    sig = tr.evaluate(t)
    sig0 = tr0.evaluate(t)
    b = design.bounds
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    labels = ["q [rad]", "dq [rad/s]", "ddq [rad/s^2]"]
    for k, ax in enumerate(axes):
        for j in range(tr.n):
            line = ax.plot(t, sig[k][:, j], lw=1.2, label=(joint_names[j] if joint_names else f"joint {j + 1}"))[0]
            ax.plot(t, sig0[k][:, j], lw=0.6, ls=":", color=line.get_color())
        ax.set_ylabel(labels[k])
        ax.grid(alpha=0.3)
    if b:
        for s in (1, -1):
            axes[1].axhline(s * max(b["max_velocity"]), color="k", ls="--", lw=0.8)
            axes[2].axhline(s * max(b["max_acceleration"]), color="k", ls="--", lw=0.8)
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    axes[0].set_title(
        f"Fourier excitation: condition number {design.condition_initial:.3g} (dotted, start) -> "
        f"{design.condition_optimized:.3g} (solid, optimized)"
    )
    return fig
