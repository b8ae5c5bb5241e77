"""Seeing the scene: MP4 videos and PNG stills rendered offscreen (EGL), run observers, progress bars only
on a terminal."""

from __future__ import annotations

import io
import math
import sys

import matplotlib.image
import numpy as np
import pytest

from reflexarm._progress import show_progress
from reflexarm.errors import ConfigError, SimulationError
from reflexarm.robots import load_robot
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim import EndEffectorForce, Plant, SensorNoise, run_closed_loop
from reflexarm.sim.run_observers import observers_active, observing_runs
from reflexarm.sim.video import StillCapture, VideoRecorder, _import_imageio, frame_scene, save_still

#: A still that is not blank has many distinct colours: a uniform background has 1, the corner text on
#: it adds a handful of anti-aliasing greys; the shaded arm adds hundreds.
MIN_COLOURS = 50


class HoldGravity:
    """tau = K_p (q_d - q) - K_d dq + g(q): holds the posture, so that a run is a still scene."""

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


def _plant(robot, scene=None) -> Plant:
    return Plant(robot, scene=scene, noise=SensorNoise.none())


def _colours(image: np.ndarray) -> int:
    rgb = np.round(255 * image[..., :3]).astype(np.int64) if image.dtype.kind == "f" else image[..., :3]
    return len(np.unique(rgb.reshape(-1, 3), axis=0))


def test_video_decodes_to_the_expected_frames_and_size(robot, tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    plant = _plant(robot)
    path = tmp_path / "run.mp4"
    duration, fps = 0.5, 20.0
    with VideoRecorder(path, fps=fps, width=160, height=128) as video:
        run_closed_loop(plant, HoldGravity(robot), Hold(robot.home), duration, callback=video)
    expected = math.ceil(duration * fps)  # frames at t = 0, 0.05, ..., 0.45 s
    assert video.frames == expected
    reader = imageio.get_reader(path)
    frames = [np.asarray(f) for f in reader]
    reader.close()
    assert len(frames) == expected
    assert frames[0].shape == (128, 160, 3)
    assert _colours(frames[0]) >= MIN_COLOURS


def test_video_refuses_sizes_h264_cannot_hold(tmp_path):
    with pytest.raises(ConfigError, match=r"frame width must be a positive multiple of 16 pixels .*got 100"):
        VideoRecorder(tmp_path / "x.mp4", width=100)
    with pytest.raises(ConfigError, match=r"fps must be a positive number of frames per second; got 0"):
        VideoRecorder(tmp_path / "x.mp4", fps=0)


def test_video_without_imageio_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(ConfigError, match=r"pip install reflexarm\[video\]; missing: imageio"):
        _import_imageio()


def test_still_is_a_png_of_the_requested_size_and_not_blank(robot, tmp_path):
    path = save_still(_plant(robot), tmp_path / "still.png", width=320, height=240)
    image = matplotlib.image.imread(path)
    assert image.shape[:2] == (240, 320)
    assert _colours(image) >= MIN_COLOURS


def test_the_camera_frames_arm_and_scene(robot):
    """Every corner of every framed geom's bounding box lies within the camera's distance of the point it
    looks at: the whole scene is in front of the camera, none behind it."""
    plant = _plant(robot)
    view = frame_scene(plant)
    m, d = plant.model, plant.data
    centres = d.geom_xpos[m.geom_type != 0]  # 0: planes, left out
    far = np.linalg.norm(centres - np.array(view.lookat), axis=1).max()
    assert far < view.distance


def test_still_capture_keeps_the_moment_of_contact(robot, tmp_path):
    """A 30 N end-effector force from t = 0.2 s: the still shows the push (largest external torque,
    after 0.2 s); the same run without the force shows the start."""
    push = EndEffectorForce(30.0, t_on=0.2, t_off=10.0)
    still = StillCapture()
    run_closed_loop(_plant(robot, push), HoldGravity(robot), Hold(robot.home), 0.4, callback=still)
    assert still.contact and still.peak_time is not None and still.peak_time >= 0.2
    info = still.save(tmp_path / "push.png", width=160, height=128)
    assert info["moment"] == "contact (largest external joint torque)" and info["t"] >= 0.2
    free = StillCapture()
    run_closed_loop(_plant(robot), HoldGravity(robot), Hold(robot.home), 0.1, callback=free)
    assert not free.contact
    assert free.save(tmp_path / "free.png", width=160, height=128)["moment"] == "start (no contact)"
    with pytest.raises(SimulationError, match="was not called by any run"):
        StillCapture().save(tmp_path / "none.png")


def test_observers_watch_every_run_in_the_block_only(robot):
    seen: list[int] = []

    def factory(plant):
        seen.append(0)
        index = len(seen) - 1

        def observe(k, p, m, cmd):
            seen[index] += 1

        return observe

    assert not observers_active()
    with observing_runs(factory):
        assert observers_active()
        for _ in range(2):
            run_closed_loop(_plant(robot), HoldGravity(robot), Hold(robot.home), 0.01)
    run_closed_loop(_plant(robot), HoldGravity(robot), Hold(robot.home), 0.01)
    assert seen == [10, 10]  # one observer per run, every tick; none after the block
    assert not observers_active()


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_only_on_a_terminal(robot, monkeypatch):
    assert not show_progress(True, io.StringIO())
    assert show_progress(True, _Terminal())
    assert not show_progress(False, _Terminal())
    # a log file: no bar, although asked for
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    run_closed_loop(_plant(robot), HoldGravity(robot), Hold(robot.home), 0.2, progress=True)
    assert log.getvalue() == ""
    # a terminal: the bar is drawn (so the check above can fail)
    tty = _Terminal()
    monkeypatch.setattr(sys, "stderr", tty)
    run_closed_loop(_plant(robot), HoldGravity(robot), Hold(robot.home), 0.2, progress=True)
    assert "simulating" in tty.getvalue()


def test_take_compiled_refuses_a_used_capture_or_another_state_mask(robot):
    """One capture per run, and only states taken with the mask a still renders (mjSTATE_INTEGRATION)."""
    import mujoco

    from reflexarm.sim.run_observers import CompiledStill

    plant = _plant(robot)
    cmd = Command(np.zeros(robot.n), np.zeros(robot.n), False, (), "hold", "")
    size = mujoco.mj_stateSize(plant.model, mujoco.mjtState.mjSTATE_INTEGRATION)
    record = CompiledStill(
        spec=int(mujoco.mjtState.mjSTATE_INTEGRATION), start_tick=0, start_state=np.zeros(size), start_time=0.0,
        start_command=cmd, peak_tick=None, peak_state=None, peak_time=None, peak_command=None, peak2=0.0,
    )  # fmt: skip
    wrong = CompiledStill(**{**record.__dict__, "spec": int(mujoco.mjtState.mjSTATE_PHYSICS)})
    with pytest.raises(SimulationError, match=f"mask {int(mujoco.mjtState.mjSTATE_PHYSICS)}.*needs"):
        StillCapture().take_compiled(plant, wrong)
    cap = StillCapture()
    cap.take_compiled(plant, record)
    assert cap.plant is plant and not cap.contact and cap.peak_time is None
    with pytest.raises(SimulationError, match="already seen a run"):
        cap.take_compiled(plant, record)
