"""See the scene: MP4 video of a closed-loop run and PNG stills, rendered offscreen by MuJoCo.

:class:`VideoRecorder` is a :func:`~reflexarm.sim.run_closed_loop` callback that renders a frame at a
chosen rate and writes an H.264 MP4 (imageio + imageio-ffmpeg, the optional extra ``video``:
``pip install reflexarm[video]``). :class:`StillCapture` is a callback that keeps the plant's state at
contact (the tick of the largest true external joint torque; the first tick when nothing touches the
arm) and renders it to a PNG afterwards (matplotlib only). :func:`save_still` renders the plant as it is
now. The camera frames the arm and the scene objects from their bounding boxes (:func:`frame_scene`);
contact forces are drawn as arrows; time, mode and detection state are written in the top-left corner.

Headless rendering needs ``MUJOCO_GL=egl`` before ``mujoco`` is first imported: ``import reflexarm``
sets it on a Linux machine without a display when it is unset (see ``reflexarm/__init__.py``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import mujoco
import numpy as np

from reflexarm.errors import ConfigError, SimulationError

if TYPE_CHECKING:
    from reflexarm.signals import Command, Measurement
    from reflexarm.sim.plant import Plant

__all__ = ["CameraView", "StillCapture", "VideoRecorder", "frame_scene", "render_frame", "save_still"]

#: Frame size of videos and stills [px] (width, height): multiples of 16, as H.264 macroblocks need.
DEFAULT_SIZE = (640, 480)
#: Default video rate [frames per second of simulated time].
DEFAULT_FPS = 30.0
#: Below this |tau_ext| [Nm] on every joint nothing touches the arm: the still shows the start instead.
#: The true external torque is exactly 0 without contact or applied force; 1 mNm is far below any force
#: worth a picture and above round-off.
CONTACT_TORQUE = 1e-3
#: Free-camera elevation [deg] (negative: looking down) and the room left around the framed box [-].
DEFAULT_ELEVATION = -20.0
FRAME_MARGIN = 1.1
#: Scene objects whose centre is farther from the arm's bounding-box centre than this many times the
#: box's half diagonal are out of the way (parked), not part of the picture [-].
NEAR_FACTOR = 3.0
#: Length of a contact force arrow per newton [m/N]: 100 N draws 0.3 m, the size of a forearm.
FORCE_ARROW_SCALE = 0.003
#: Diameter of a contact force arrow and of a contact point's disc [m].
FORCE_ARROW_WIDTH = 0.012
CONTACT_POINT_WIDTH = 0.03
#: Lower bounds of the headlight's ambient and diffuse intensity [-] (MuJoCo's default 0.1 / 0.4 leaves
#: an arm without scene lights nearly black).
HEADLIGHT_AMBIENT = 0.35
HEADLIGHT_DIFFUSE = 0.6


class CameraView(NamedTuple):
    """A MuJoCo free camera: point looked at [m], distance [m], azimuth and elevation [deg]."""

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float


def _scene_geoms(plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """(arm geoms, other geoms) worth framing: planes (infinite floors) are left out."""
    m = plant.model
    arm = np.isin(m.geom_bodyid, plant._arm_bodies)
    finite = m.geom_type != int(mujoco.mjtGeom.mjGEOM_PLANE)
    return np.flatnonzero(arm & finite), np.flatnonzero(~arm & finite)


def _corners(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """World coordinates (8 * len(geoms), 3) of the corners of the geoms' bounding boxes."""
    if geoms.size == 0:
        return np.zeros((0, 3))
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    aabb = model.geom_aabb[geoms]  # (g, 6): centre and half sizes in the geom's frame
    local = aabb[:, None, :3] + signs[None, :, :] * aabb[:, None, 3:]
    rot = data.geom_xmat[geoms].reshape(-1, 3, 3)
    world = data.geom_xpos[geoms][:, None, :] + np.einsum("gij,gkj->gki", rot, local)
    return world.reshape(-1, 3)


def frame_scene(
    plant: Plant,
    *,
    data: mujoco.MjData | None = None,
    azimuth: float | None = None,
    elevation: float = DEFAULT_ELEVATION,
    aspect: float = DEFAULT_SIZE[0] / DEFAULT_SIZE[1],
) -> CameraView:
    """A camera that shows the whole arm and every scene object of ``plant`` (state of ``data``).

    The camera looks at the centre of the bounding box of the arm's and the scene's geoms (floors left
    out), from far enough that the box's enclosing sphere fits the narrower field of view. Without
    ``azimuth`` it looks across the line from the arm to the scene objects, so neither hides the other.
    """
    m = plant.model
    d = plant.data if data is None else data
    arm, other = _scene_geoms(plant)
    arm_pts, other_pts = _corners(m, d, arm), _corners(m, d, other)
    if arm_pts.shape[0] and other.size:
        # scene objects parked far from the arm (the elbow stick waits 50 m below) are left out
        lo_arm, hi_arm = arm_pts.min(axis=0), arm_pts.max(axis=0)
        reach = NEAR_FACTOR * max(0.5 * float(np.linalg.norm(hi_arm - lo_arm)), 0.1)
        near = np.linalg.norm(d.geom_xpos[other] - 0.5 * (lo_arm + hi_arm), axis=1) <= reach
        other_pts = _corners(m, d, other[near])
    pts = np.vstack([arm_pts, other_pts])
    if pts.shape[0] == 0:
        raise SimulationError("the plant has no finite geometry to frame (only planes)")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.05)
    if azimuth is None:
        azimuth = 135.0
        if other_pts.shape[0] and arm_pts.shape[0]:
            v = other_pts.mean(axis=0) - arm_pts.mean(axis=0)
            if math.hypot(v[0], v[1]) > 1e-6:
                azimuth = math.degrees(math.atan2(v[1], v[0])) - 90.0
    fovy = math.radians(float(m.vis.global_.fovy))
    half = 0.5 * min(fovy, 2.0 * math.atan(math.tan(0.5 * fovy) * aspect))
    distance = FRAME_MARGIN * radius / math.sin(half)
    return CameraView((float(centre[0]), float(centre[1]), float(centre[2])), distance, float(azimuth), elevation)


def _check_size(width: int, height: int) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 16 or v % 16:
            raise ConfigError(
                f"frame {name} must be a positive multiple of 16 pixels (H.264 macroblocks); got {v!r}; e.g. "
                f"{DEFAULT_SIZE[0]} x {DEFAULT_SIZE[1]}"
            )
    return int(width), int(height)


class _Painter:
    """A MuJoCo offscreen renderer for one plant, with the scene options of the videos and stills."""

    def __init__(self, plant: Plant, width: int, height: int, camera: CameraView | None) -> None:
        if os.environ.get("MUJOCO_GL", "") == "" and not os.environ.get("DISPLAY"):
            raise SimulationError(
                "offscreen rendering needs MUJOCO_GL=egl set before mujoco is imported (import reflexarm first, "
                "or set MUJOCO_GL=egl in the environment); got MUJOCO_GL unset and no DISPLAY"
            )
        self.plant, self.width, self.height, self.camera_view = plant, width, height, camera
        m = plant.model
        g, q = m.vis.global_, m.vis.quality
        saved = (g.offwidth, g.offheight, q.offsamples)
        # the offscreen buffer must hold the frame; 0 multisamples: 2x faster, edges a bit rougher
        g.offwidth, g.offheight, q.offsamples = max(g.offwidth, width), max(g.offheight, height), 0
        try:
            self.renderer = mujoco.Renderer(m, height, width)
        except Exception as e:
            raise SimulationError(
                f"MuJoCo cannot render offscreen (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r}): {e}"
            ) from e
        finally:
            g.offwidth, g.offheight, q.offsamples = saved
        opt = mujoco.MjvOption()
        opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
        opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = True
        opt.flags[mujoco.mjtVisFlag.mjVIS_TRANSPARENT] = True  # arrows inside a body stay visible
        opt.flags[mujoco.mjtVisFlag.mjVIS_PERTFORCE] = True  # applied forces (xfrc_applied: force steps)
        self.option = opt
        scn = self.renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False  # 4x faster offscreen, see notes/bags-and-video.md
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False

    def render(self, data: mujoco.MjData, text: str = "") -> np.ndarray:
        """The (height, width, 3) uint8 image of ``data``'s state, ``text`` in the top-left corner."""
        m = self.plant.model
        view = self.camera_view or frame_scene(self.plant, data=data, aspect=self.width / self.height)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = view.lookat
        cam.distance, cam.azimuth, cam.elevation = view.distance, view.azimuth, view.elevation
        light, scale, size = m.vis.headlight, m.vis.scale, float(m.stat.meansize)
        saved = (
            float(m.vis.map.force),
            light.ambient.copy(),
            light.diffuse.copy(),
            float(scale.forcewidth),
            float(scale.contactwidth),
            float(scale.contactheight),
        )
        # drawing settings only, restored at once (the physics never reads them). MuJoCo draws a contact
        # force F as an arrow F * map.force / meanmass long and sizes arrows and contact points relative to
        # meansize, which an object parked far away inflates: set them in metres. The headlight lights a
        # scene without lights of its own.
        m.vis.map.force = FORCE_ARROW_SCALE * float(m.stat.meanmass)
        scale.forcewidth = FORCE_ARROW_WIDTH / size
        scale.contactwidth, scale.contactheight = CONTACT_POINT_WIDTH / size, 0.2 * CONTACT_POINT_WIDTH / size
        light.ambient = np.maximum(light.ambient, HEADLIGHT_AMBIENT)
        light.diffuse = np.maximum(light.diffuse, HEADLIGHT_DIFFUSE)
        try:
            self.renderer.update_scene(data, camera=cam, scene_option=self.option)
        finally:
            m.vis.map.force, light.ambient, light.diffuse = saved[:3]
            scale.forcewidth, scale.contactwidth, scale.contactheight = saved[3:]
        image = np.asarray(self.renderer.render())
        return _draw_text(image, text) if text else image

    def close(self) -> None:
        self.renderer.close()


def _draw_text(image: np.ndarray, text: str) -> np.ndarray:
    """``text`` on a dark band in the image's top-left corner (Pillow, a matplotlib dependency)."""
    from PIL import Image, ImageDraw

    pic = Image.fromarray(image)
    draw = ImageDraw.Draw(pic)
    box = draw.multiline_textbbox((6, 4), text)
    draw.rectangle((0, 0, box[2] + 6, box[3] + 4), fill=(0, 0, 0))
    draw.multiline_text((6, 4), text, fill=(255, 255, 255))
    return np.asarray(pic)


def _status(plant: Plant, t: float, cmd: Command | None) -> str:
    """Time, mode and detection state for the corner of a frame; joints 1-based with their names."""
    line = f"t = {t:6.3f} s"
    if cmd is None:
        return line
    line += f"   mode: {cmd.mode}"
    if cmd.collision:
        names = plant.joint_names
        joints = ", ".join(f"{j + 1} ({names[j]})" for j in cmd.collided_joints)
        return f"{line}\nCOLLISION detected: joint {joints}" if joints else f"{line}\nCOLLISION detected"
    return line


def render_frame(plant: Plant, *, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]) -> np.ndarray:
    """The plant as it is now, as an (height, width, 3) uint8 image framed by :func:`frame_scene`."""
    width, height = _check_size(width, height)
    painter = _Painter(plant, width, height, None)
    try:
        return painter.render(plant.data, f"t = {plant.time:6.3f} s")
    finally:
        painter.close()


def _write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    import matplotlib.image

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(out, image)
    return out


def save_still(
    plant: Plant, path: str | os.PathLike[str], *, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]
) -> Path:
    """Render the plant as it is now to a PNG at ``path`` (folders created); returns the path."""
    return _write_png(path, render_frame(plant, width=width, height=height))


class StillCapture:
    """A run callback that keeps the state at contact, to render a still of it afterwards.

    It keeps MuJoCo's integration state at the first tick and at the tick of the largest true external
    joint torque (max over joints of |tau_ext|, :meth:`Plant.true_external_torque`): the moment the scene
    presses hardest on the arm. :meth:`save` renders the contact state when the peak reached
    :data:`CONTACT_TORQUE`, else the first tick. One capture per run.
    """

    def __init__(self) -> None:
        self.plant: Plant | None = None
        self.peak_torque = 0.0  #: largest max_j |tau_ext,j| seen [Nm]
        self.peak_time: float | None = None  #: its time [s]
        self._start: np.ndarray | None = None
        self._peak: np.ndarray | None = None
        self._start_cmd: Command | None = None
        self._peak_cmd: Command | None = None
        self._buf = np.zeros(0)

    def __call__(self, k: int, plant: Plant, measurement: Measurement, command: Command) -> None:
        if self.plant is None:
            self.plant, self._buf = plant, np.zeros(plant.n)
            self._start, self._start_cmd = self._state(plant), command
        peak = float(np.max(np.abs(plant.true_external_torque(out=self._buf)), initial=0.0))
        if peak > self.peak_torque:
            self.peak_torque, self.peak_time = peak, plant.time
            self._peak, self._peak_cmd = self._state(plant), command

    @staticmethod
    def _state(plant: Plant) -> np.ndarray:
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(plant.model, spec))
        mujoco.mj_getState(plant.model, plant.data, state, spec)
        return state

    @property
    def contact(self) -> bool:
        """True when something pressed on the arm during the run (peak >= :data:`CONTACT_TORQUE`)."""
        return self.peak_torque >= CONTACT_TORQUE

    def save(
        self, path: str | os.PathLike[str], *, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]
    ) -> dict[str, Any]:
        """Render the still to a PNG; returns what it shows (``moment``, ``t``, ``peak_external_torque_Nm``).

        Raises:
            SimulationError: the capture has not seen a run.
        """
        if self.plant is None or self._start is None:
            raise SimulationError("no still to save: this StillCapture was not called by any run")
        width, height = _check_size(width, height)
        plant = self.plant
        state, cmd = (self._peak, self._peak_cmd) if self.contact else (self._start, self._start_cmd)
        data = mujoco.MjData(plant.model)
        mujoco.mj_setState(plant.model, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(plant.model, data)  # positions and contact forces of that state, for the arrows
        painter = _Painter(plant, width, height, None)
        try:
            image = painter.render(data, _status(plant, float(data.time), cmd))
        finally:
            painter.close()
        out = _write_png(path, image)
        return {
            "file": out.name,
            "moment": "contact (largest external joint torque)" if self.contact else "start (no contact)",
            "t": float(data.time),
            "peak_external_torque_Nm": self.peak_torque,
        }


class VideoRecorder:
    """A run callback that renders frames at ``fps`` (of simulated time) into an H.264 MP4.

    Use as ``run_closed_loop(..., callback=VideoRecorder("run.mp4"))``, then :meth:`close` (or as a
    context manager). The camera is framed once, on the first frame (:func:`frame_scene`), unless given.
    A frame is taken at the first tick at or after each multiple of ``1/fps`` from the run's start: a run
    of N ticks of period dt gives ``ceil(N dt fps)`` frames (when ``fps`` <= 1/dt).

    Args:
        path: the ``.mp4`` file to write (folders created).
        fps: frames per second of simulated time; the file plays at this rate (real time).
        width, height: frame size [px], multiples of 16.
        camera: a fixed camera; default framed from the first frame's state.
        overlay: write time, mode and detection state in the top-left corner.

    Raises:
        ConfigError: bad size or rate, or imageio / imageio-ffmpeg missing (``pip install reflexarm[video]``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        fps: float = DEFAULT_FPS,
        width: int = DEFAULT_SIZE[0],
        height: int = DEFAULT_SIZE[1],
        camera: CameraView | None = None,
        overlay: bool = True,
    ) -> None:
        self.width, self.height = _check_size(width, height)
        if not isinstance(fps, (int, float)) or not math.isfinite(fps) or fps <= 0:
            raise ConfigError(f"fps must be a positive number of frames per second; got {fps!r}")
        self.path, self.fps, self.camera, self.overlay = Path(path), float(fps), camera, overlay
        self.frames = 0  #: frames written so far
        self._imageio = _import_imageio()
        self._writer: Any = None
        self._painter: _Painter | None = None
        self._t0 = 0.0

    def __call__(self, k: int, plant: Plant, measurement: Measurement, command: Command) -> None:
        t = plant.time
        if self._painter is None:
            view = self.camera or frame_scene(plant, aspect=self.width / self.height)
            self._painter = _Painter(plant, self.width, self.height, view)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = self._imageio.get_writer(
                self.path, fps=self.fps, codec="libx264", pixelformat="yuv420p", macro_block_size=16
            )
            self._t0 = t
        # half a tick of slack so that round-off in the time never skips or doubles a frame
        if t - self._t0 + 0.5 * plant.control_period < self.frames / self.fps:
            return
        text = _status(plant, t, command) if self.overlay else ""
        self._writer.append_data(self._painter.render(plant.data, text))
        self.frames += 1

    def close(self) -> None:
        """Finish the file (idempotent)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._painter is not None:
            self._painter.close()
            self._painter = None

    def __enter__(self) -> VideoRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _import_imageio() -> Any:
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (the bundled ffmpeg with libx264)
    except ImportError as e:
        raise ConfigError(
            f"video needs the optional extra 'video' (imageio + imageio-ffmpeg): pip install reflexarm[video]; "
            f"missing: {e.name}"
        ) from e
    return imageio
