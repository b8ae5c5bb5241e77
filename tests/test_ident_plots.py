"""The identification figures draw what they are given: the data in the lines, the numbers in the labels."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest

from reflexarm.ident import FourierTrajectory, FrictionPoint, TorqueValidation, fit_friction
from reflexarm.ident.excitation.design import ExcitationDesign
from reflexarm.ident.plots import excitation_figure, friction_figure, plot_friction, torque_validation_figure


def _fit(joint, mu, dv, offset=0.5, speeds=(0.2, 0.5, 1.0)):
    pts = [
        FrictionPoint(joint, s * v, dv * s * v + mu * s + offset, 0.01, 100, 0.0, 1.0) for v in speeds for s in (1, -1)
    ]
    return fit_friction(pts, offset=True)


def _lines(ax):
    return {line.get_label(): line for line in ax.get_lines()}


def test_friction_figure_draws_the_points_the_fit_and_the_truth():
    fits = [_fit(0, 2.0, 1.3), _fit(2, 10.3, 1.6)]
    truth = (np.array([2.0, 6.7, 10.3]), np.array([1.3, 0.9, 1.6]))
    fig = friction_figure(fits, joint_names=["shz", "shx", "ely"], truth=truth)
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in visible] == ["joint 1 shz", "joint 3 ely"]
    for ax, f in zip(visible, fits, strict=True):
        lines = _lines(ax)
        assert set(lines) == {
            "constant-velocity runs",
            f"fit: mu_C {f.coulomb:.2f} Nm, d_v {f.viscous:.2f} Nms/rad",
            f"true: {truth[0][f.joint]:.2f}, {truth[1][f.joint]:.2f}",
        }
        # the markers are the points with the fitted offset removed (exact points: the law itself)
        x, y = lines["constant-velocity runs"].get_data()
        np.testing.assert_allclose(x, [p.velocity for p in f.points])
        np.testing.assert_allclose(y, f.viscous * np.asarray(x) + f.coulomb * np.sign(x), atol=1e-9)
        # the fitted law's line is mu_C sgn(v) + d_v v on its own grid
        gx, gy = lines[f"fit: mu_C {f.coulomb:.2f} Nm, d_v {f.viscous:.2f} Nms/rad"].get_data()
        np.testing.assert_allclose(gy, f.viscous * np.asarray(gx) + f.coulomb * np.sign(gx), atol=1e-12)
        assert ax.get_xlabel() == "dq [rad/s]" and ax.get_ylabel() == "tau_f [Nm] (offset removed)"
    assert "cf. Fig. 4" in fig.texts[0].get_text()
    plt.close(fig)


def test_torque_validation_figure_draws_measured_and_each_model_with_its_mse():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 2.0, 0.01)
    measured = np.column_stack([np.sin(t), np.cos(t), 2 * t])
    vals = {
        m: TorqueValidation(t, measured, measured + rng.normal(0, s, measured.shape), m)
        for m, s in (("combined", 0.5), ("sequential", 0.1))
    }
    fig = torque_validation_figure(vals, joint_names=["a", "b", "c"], joints=[0, 2], window=(0.5, 1.5))
    assert len(fig.axes) == 2
    inside = (t >= 0.5) & (t <= 1.5)
    for ax, j, name in zip(fig.axes, (0, 2), ("a", "c"), strict=True):
        lines = _lines(ax)
        labels = [f"{m} (MSE {v.mse[j]:.3g})" for m, v in vals.items()]
        assert list(lines) == ["tau_m measured", *labels]
        np.testing.assert_array_equal(lines["tau_m measured"].get_xdata(), t[inside])
        np.testing.assert_array_equal(lines["tau_m measured"].get_ydata(), measured[inside, j])
        for label, v in zip(labels, vals.values(), strict=True):
            np.testing.assert_array_equal(lines[label].get_ydata(), v.predicted[inside, j])
        assert ax.get_ylabel() == f"{j + 1} {name}\n[Nm]"
        # the legend shows the MSE of the model that is worse by construction as the larger number
        assert vals["combined"].mse[j] > vals["sequential"].mse[j]
    assert fig.axes[-1].get_xlabel() == "t [s]"
    plt.close(fig)


def test_excitation_figure_draws_both_trajectories_and_the_bounds():
    rng = np.random.default_rng(1)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.1 * rng.normal(size=(2, 3)), 0.1 * rng.normal(size=(2, 3)), np.zeros(2))
    start = FourierTrajectory(tr.base_frequency, 0.5 * tr.a, 0.5 * tr.b, tr.offset)
    bounds = {"lower": [-1.0, -1.0], "upper": [1.0, 1.0], "max_velocity": [1.5, 1.2], "max_acceleration": [5.0, 4.0]}
    design = ExcitationDesign(tr, start, 812.0, 41.5, {}, {}, 10, "ok", bounds)
    fig = excitation_figure(design, joint_names=["j1", "j2"])
    q_ax, dq_ax, ddq_ax = fig.axes
    assert [ax.get_ylabel() for ax in fig.axes] == ["q [rad]", "dq [rad/s]", "ddq [rad/s^2]"]
    assert q_ax.get_title() == "Fourier excitation: condition number 812 (dotted, start) -> 41.5 (solid, optimized)"
    t = q_ax.get_lines()[0].get_xdata()
    for k, ax in enumerate(fig.axes):
        lines = ax.get_lines()
        # per joint: the optimized trajectory (solid), then the start (dotted), then the bounds (dashed)
        for j in range(2):
            np.testing.assert_allclose(lines[2 * j].get_ydata(), tr.evaluate(t)[k][:, j], atol=1e-12)
            np.testing.assert_allclose(lines[2 * j + 1].get_ydata(), start.evaluate(t)[k][:, j], atol=1e-12)
            assert lines[2 * j + 1].get_linestyle() == ":"
        bound_levels = sorted(line.get_ydata()[0] for line in lines[4:])
        expected = {0: [], 1: [-1.5, 1.5], 2: [-5.0, 5.0]}[k]
        assert bound_levels == pytest.approx(expected)
    assert [text.get_text() for text in q_ax.get_legend().get_texts()] == ["j1", "j2"]
    plt.close(fig)


def test_plot_writes_a_png(tmp_path):
    path = plot_friction([_fit(1, 6.7, 0.9)], tmp_path / "sub" / "fig4.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
