"""The collision event drawn in stills, videos and figures (issue 15, item 6): the arrows are the scene geoms
of the estimate and the truth given, a MuJoCo arrow ends at its point (checked against a capsule drawn by the
same call), a missing or malformed estimate never fails a still, and fig. 10 marks the reaction's phases."""

from __future__ import annotations

import dataclasses
import math

import matplotlib.image
import mujoco
import numpy as np
import pytest

from reflexarm.robots import load_robot
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim import EndEffectorForce, Plant, SensorNoise, run_closed_loop
from reflexarm.sim._event_drawing import (
    ARROW_DRAWN_SHARE,
    ESTIMATE_RGBA,
    TRUTH_RGBA,
    ForceArrow,
    add_force_arrows,
)
from reflexarm.sim._rendering import _Painter
from reflexarm.sim.video import StillCapture, VideoRecorder

#: MjvGeom stores positions and orientations in float32: 2^-24 relative, ~1e-7 m at 1 m; 1e-6 is the
#: tolerance of a value that went through float32 once.
GEOM_ATOL = 1e-6
#: The drawn arrow's length against the capsule drawn by the same call (its scale), relative: the head's
#: point thins below a pixel and fades into the background over the last few pixels (measured 0.96 of
#: 0.4 m at ~270 px/m); an arrow drawn half as long, as MuJoCo draws size[2] uncorrected, gives 0.5.
DRAWN_LENGTH_SHARE_TOL = 0.1
#: Diameter of the reference capsule [m].
CAPSULE_WIDTH = 0.025
#: Time the fabricated detection happens in the runs below [s] (the 30 N force acts from 0.2 s).
T_DETECT = 0.25


class HoldGravity:
    """tau = K_p (q_d - q) - K_d dq + g(q): holds the posture (as in tests/test_video.py)."""

    def __init__(self, robot) -> None:
        self.robot = robot

    def reset(self) -> None:
        pass

    def step(self, m: Measurement, r: Reference) -> Command:
        tau = 200.0 * (r.q_d - m.q) - 20.0 * m.dq + self.robot.compute_gravity(m.q)
        return Command(tau, np.zeros(self.robot.n), False, (), "hold", "")


class Hold:
    def __init__(self, q: np.ndarray) -> None:
        self.q = q

    def sample(self, t: float) -> Reference:
        return Reference(self.q, np.zeros_like(self.q), np.zeros_like(self.q))


@pytest.fixture(scope="module")
def robot():
    return load_robot("atlas_v5_left_arm")


def _event(t_detect: float, reaction: str = "brake") -> dict:
    return {
        "t_detect": t_detect,
        "joints": [0],
        "joints_1based": [1],
        "contact_class": "contact",
        "reaction": reaction,
        "phase": "holding",
        "text": "",
        "guard_checked": True,
    }


def _estimate(point, force) -> dict:
    return {
        "link": 6,
        "link_name": "wrist_ft",
        "point": None if point is None else list(point),
        "force": None if force is None else list(force),
        "determined": "point_and_force" if point is not None else "link_only",
        "reason": "point undetermined, force undetermined: test" if point is None else "measured",
    }


@pytest.fixture(scope="module")
def pushed_run(robot):
    """A 30 N end-effector push from 0.2 s on a held Atlas arm, the still's capture, and the trace with a
    fabricated detection at T_DETECT (modes: braking, then holding from 0.3 s)."""
    plant = Plant(robot, scene=EndEffectorForce(30.0, t_on=0.2, t_off=10.0), noise=SensorNoise.none())
    still = StillCapture()
    trace = run_closed_loop(plant, HoldGravity(robot), Hold(robot.home), 0.4, callback=still)
    collision = trace.t >= T_DETECT - 1e-9
    mode = np.where(trace.t < T_DETECT - 1e-9, "compliant", np.where(trace.t < 0.3 - 1e-9, "braking", "holding"))
    trace = dataclasses.replace(
        trace, collision=collision, mode=mode, meta={**trace.meta, "collision_event": _event(T_DETECT)}
    )
    return plant, still, trace


def test_the_arrow_geoms_are_the_estimate_and_the_truth_given(robot):
    plant = Plant(robot, noise=SensorNoise.none())
    estimate = ForceArrow(np.array([0.4, 0.3, 0.8]), np.array([-10.0, 40.0, -5.0]), "estimate 41 N", ESTIMATE_RGBA)
    truth = ForceArrow(np.array([0.45, 0.3, 0.78]), np.array([-12.0, 38.0, -6.0]), "true 40 N", TRUTH_RGBA, -0.08)
    painter = _Painter(plant, 160, 128, None)
    try:
        painter.render(plant.data, "", [estimate, truth])
        geoms = [painter.renderer.scene.geoms[i] for i in painter.arrow_geoms]
        assert len(geoms) == 2
        for g, arrow in zip(geoms, (estimate, truth), strict=True):
            u = arrow.force / np.linalg.norm(arrow.force)
            assert g.type == mujoco.mjtGeom.mjGEOM_ARROW
            axis = np.asarray(g.mat, dtype=float).reshape(3, 3)[:, 2]  # the arrow points along its z axis
            np.testing.assert_allclose(axis, u, atol=GEOM_ATOL, err_msg="arrow direction != the force's")
            length = float(g.size[2]) * ARROW_DRAWN_SHARE
            np.testing.assert_allclose(length, arrow.length, rtol=GEOM_ATOL)
            tip = np.asarray(g.pos, dtype=float) + length * axis
            np.testing.assert_allclose(tip, arrow.point, atol=GEOM_ATOL, err_msg="the arrow does not end at its point")
            np.testing.assert_allclose(np.asarray(g.rgba), arrow.rgba, atol=GEOM_ATOL)
        labels = {str(g.label) for g in painter.renderer.scene.geoms[: painter.renderer.scene.ngeom] if g.label}
        assert {"estimate 41 N", "true 40 N"} <= labels
    finally:
        painter.close()


def test_an_arrow_as_drawn_ends_at_its_point():
    """Rendered top-down beside a capsule from the same tail to the same point: the arrow's tip reaches the
    capsule's end (MuJoCo 4.0 draws an arrow ARROW_DRAWN_SHARE of its size[2]; add_force_arrows sets it so)."""
    xml = '<mujoco><visual><global offwidth="640"/></visual><worldbody><light pos="0 0 3"/></worldbody></mujoco>'
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    renderer = mujoco.Renderer(m, 240, 640)
    try:
        cam = mujoco.MjvCamera()
        cam.lookat[:], cam.distance, cam.azimuth, cam.elevation = (0.1, 0.0, 0.0), 1.2, 90.0, -90.0
        renderer.update_scene(d, camera=cam)
        arrow = ForceArrow(np.array([0.3, 0.1, 0.0]), np.array([50.0, 0.0, 0.0]), "", (0.0, 1.0, 0.0, 1.0))
        (i,) = add_force_arrows(renderer.scene, [arrow])
        scn = renderer.scene
        scn.geoms[i + 1].rgba[:] = 0.0  # hide the point's sphere: measure the arrow alone
        cap = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(
            cap,
            mujoco.mjtGeom.mjGEOM_CAPSULE,
            np.zeros(3),
            np.zeros(3),
            np.eye(3).ravel(),
            np.array([1.0, 0.0, 0.0, 1.0], np.float32),
        )
        mujoco.mjv_connector(
            cap, mujoco.mjtGeom.mjGEOM_CAPSULE, CAPSULE_WIDTH, arrow.tail - [0, 0.2, 0], arrow.point - [0, 0.2, 0]
        )
        scn.ngeom += 1
        image = renderer.render().astype(int)
    finally:
        renderer.close()
    green = (image[..., 1] > 30) & (image[..., 0] < 30)  # the head's anti-aliased point too
    red = (image[..., 0] > 120) & (image[..., 1] < 80)
    gx, rx = np.flatnonzero(green.any(axis=0)), np.flatnonzero(red.any(axis=0))
    assert gx.size and rx.size
    px_per_m = (rx.max() - rx.min()) / (arrow.length + CAPSULE_WIDTH)  # the capsule's round ends add its width
    drawn = (gx.max() - gx.min()) / px_per_m
    assert abs(drawn / arrow.length - 1.0) < DRAWN_LENGTH_SHARE_TOL, (
        f"the arrow is drawn {drawn:.3f} m, not {arrow.length} m"
    )


def test_event_still_draws_the_estimate_beside_the_truth(robot, pushed_run, tmp_path):
    plant, still, trace = pushed_run
    k = int(np.flatnonzero(trace.collision)[0])
    point, force = np.array([0.5, 0.3, 0.9]), np.array([1.0, -25.0, 3.0])
    run = dataclasses.replace(trace, meta={**trace.meta, "contact_estimate": _estimate(point, force)})
    info = still.save_event(tmp_path / "event.png", run, width=320, height=240)
    assert matplotlib.image.imread(tmp_path / "event.png").shape[:2] == (240, 320)
    assert info["moment"] == "detection" and info["t"] == pytest.approx(trace.t[k]) and info["notes"] == []
    est, true = info["arrows"]
    np.testing.assert_array_equal(est["point_m"], point)
    np.testing.assert_array_equal(est["force_N"], force)
    # the truth: the force beyond the wrist sensor at the detecting tick, at the end effector then
    np.testing.assert_array_equal(true["force_N"], trace.f_ext_ee[k])
    np.testing.assert_allclose(true["point_m"], robot.compute_frame_pose(trace.q[k], robot.ee_frame)[1], atol=1e-12)
    assert np.linalg.norm(trace.f_ext_ee[k]) == pytest.approx(30.0, rel=1e-6)
    assert true["label"] == "true 30 N" and est["label"] == f"estimate {np.linalg.norm(force):.0f} N"


@pytest.mark.parametrize(
    ("estimate", "note"),
    [
        (None, "no contact_estimate"),
        (_estimate(None, None), "no arrow: point undetermined, force undetermined: test"),
        (_estimate([0.5, math.nan, 0.9], [1.0, 2.0, 3.0]), "must be 3 finite numbers"),
        ("not a record", "no contact_estimate"),
    ],
)
def test_a_missing_estimate_never_fails_the_still(pushed_run, tmp_path, estimate, note):
    _, still, trace = pushed_run
    meta = {**trace.meta, "contact_estimate": estimate} if estimate != "not a record" else {**trace.meta}
    info = still.save_event(tmp_path / "event.png", dataclasses.replace(trace, meta=meta), width=160, height=128)
    assert (tmp_path / "event.png").is_file()
    assert [a["label"] for a in info["arrows"]] == ["true 30 N"]  # the truth is still drawn
    assert any(note in n for n in info["notes"]), info["notes"]


def test_a_run_without_detection_gives_a_still_with_a_note(pushed_run, tmp_path):
    _, still, trace = pushed_run
    quiet = dataclasses.replace(trace, collision=np.zeros_like(trace.collision), meta={})
    info = still.save_event(tmp_path / "event.png", quiet, width=160, height=128)
    assert info["arrows"] == [] and info["t_detect"] is None
    assert info["notes"] == ["no detection in this run: no event to draw"]


def test_deferred_video_draws_the_event_from_detection_on(robot, tmp_path):
    pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    plant = Plant(robot, scene=EndEffectorForce(30.0, t_on=0.2, t_off=10.0), noise=SensorNoise.none())
    video = VideoRecorder(tmp_path / "run.mp4", fps=20.0, width=160, height=128, defer=True)
    trace = run_closed_loop(plant, HoldGravity(robot), Hold(robot.home), 0.4, callback=video)
    assert not (tmp_path / "run.mp4").exists()  # nothing rendered before close
    collision = trace.t >= T_DETECT - 1e-9
    video.annotate(dataclasses.replace(trace, collision=collision, meta={"collision_event": _event(T_DETECT)}))
    video.close()
    assert video.frames == 8 and (tmp_path / "run.mp4").is_file()
    assert video.event_frames == 3  # the frames at 0.25, 0.30 and 0.35 s


def test_fig10_shades_the_reaction_phases_and_states_the_guard(pushed_run, tmp_path, monkeypatch):
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon, Rectangle

    from reflexarm.experiments.plots import guard_verdict, phase_spans, plot_fig10

    _, _, trace = pushed_run
    spans = phase_spans(trace)
    assert [s[0] for s in spans] == ["braking", "holding"]
    assert spans[0][1] == pytest.approx(T_DETECT) and spans[0][2] == pytest.approx(0.3)
    assert spans[1][2] == pytest.approx(trace.t[-1])
    assert guard_verdict(trace) == "brake (contact): the arm came to rest"
    figures = []
    original = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (figures.append(self), original(self, *a, **k))[1])
    plot_fig10(trace, np.zeros_like(trace.tau_m), tmp_path / "fig10.png")
    (fig,) = figures
    top, bottom = fig.axes
    shaded = {p.get_label(): p for p in top.patches if isinstance(p, (Polygon, Rectangle)) and p.get_label()[:1] != "_"}
    assert set(shaded) == {"phase: braking", "phase: holding"}
    x = shaded["phase: braking"].get_xy()[:, 0] if isinstance(shaded["phase: braking"], Polygon) else None
    if x is not None:
        assert x.min() == pytest.approx(T_DETECT) and x.max() == pytest.approx(0.3)
    assert any("the arm came to rest" in t.get_text() for t in bottom.texts)
