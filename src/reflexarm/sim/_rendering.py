"""Offscreen rendering of a plant for :mod:`reflexarm.sim.video`: the camera that frames arm and scene,
the scene options (contact force arrows, applied forces, transparency) and the corner text."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import mujoco
import numpy as np

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.sim._event_drawing import ForceArrow, add_force_arrows

if TYPE_CHECKING:
    from reflexarm.signals import Command
    from reflexarm.sim.plant import Plant

__all__ = ["CameraView", "frame_scene", "render_frame"]

#: Frame size of videos and stills [px] (width, height): multiples of 16, as H.264 macroblocks need.
DEFAULT_SIZE = (640, 480)
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
#: Distance of the near clipping plane from the camera [m].
NEAR_CLIP = 0.01
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
    A plant without any finite geometry is framed by its bodies' origins (the still is a side product of a
    run and never fails it).
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
    if pts.shape[0] == 0:  # no finite geometry (a file of inertials only): the bodies' origins, never an error
        pts = np.vstack([np.asarray(d.xpos[1:], dtype=float).reshape(-1, 3), np.zeros((1, 3))])
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
        saved = (g.offwidth, g.offheight, q.offsamples, q.shadowsize)
        # the offscreen buffer must hold the frame; 0 multisamples: 2x faster, edges a bit rougher. No shadow
        # map: shadows are off in every frame (below), and MuJoCo's default 4096 x 4096 map costs 64 MB
        g.offwidth, g.offheight, q.offsamples, q.shadowsize = max(g.offwidth, width), max(g.offheight, height), 0, 0
        try:
            self.renderer = mujoco.Renderer(m, height, width)
        except Exception as e:
            raise SimulationError(
                f"MuJoCo cannot render offscreen (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r}): {e}"
            ) from e
        finally:
            g.offwidth, g.offheight, q.offsamples, q.shadowsize = saved
        opt = mujoco.MjvOption()
        opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
        opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = True
        opt.flags[mujoco.mjtVisFlag.mjVIS_TRANSPARENT] = True  # arrows inside a body stay visible
        opt.flags[mujoco.mjtVisFlag.mjVIS_PERTFORCE] = True  # applied forces (xfrc_applied: force steps)
        self.option = opt
        self.arrow_geoms: list[int] = []  #: scene indices of the arrows added to the last frame
        scn = self.renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False  # 4x faster offscreen, see notes/bags-and-video.md
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False

    def render(self, data: mujoco.MjData, text: str = "", arrows: Sequence[ForceArrow] = ()) -> np.ndarray:
        """The (height, width, 3) uint8 image of ``data``'s state, ``text`` in the top-left corner and
        ``arrows`` (:class:`~reflexarm.sim._event_drawing.ForceArrow`) added to the scene as MuJoCo geoms."""
        m = self.plant.model
        view = self.camera_view or frame_scene(self.plant, data=data, aspect=self.width / self.height)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = view.lookat
        cam.distance, cam.azimuth, cam.elevation = view.distance, view.azimuth, view.elevation
        light, scale, size = m.vis.headlight, m.vis.scale, float(m.stat.meansize)
        saved = (
            float(m.vis.map.znear),
            float(m.vis.map.force),
            light.ambient.copy(),
            light.diffuse.copy(),
            float(scale.forcewidth),
            float(scale.contactwidth),
            float(scale.contactheight),
        )
        # drawing settings only, restored at once (the physics never reads them). MuJoCo draws a contact
        # force F as an arrow F * map.force / meanmass long and sizes arrows and contact points relative to
        # meansize, which an object parked far away inflates: set them in metres, and the near clipping plane
        # (a share of the extent, which the parked object inflates as well). The headlight lights a
        # scene without lights of its own.
        m.vis.map.znear = NEAR_CLIP / max(float(m.stat.extent), 1e-9)
        m.vis.map.force = FORCE_ARROW_SCALE * float(m.stat.meanmass)
        scale.forcewidth = FORCE_ARROW_WIDTH / size
        scale.contactwidth, scale.contactheight = CONTACT_POINT_WIDTH / size, 0.2 * CONTACT_POINT_WIDTH / size
        light.ambient = np.maximum(light.ambient, HEADLIGHT_AMBIENT)
        light.diffuse = np.maximum(light.diffuse, HEADLIGHT_DIFFUSE)
        try:
            self.renderer.update_scene(data, camera=cam, scene_option=self.option)
        finally:
            m.vis.map.znear, m.vis.map.force, light.ambient, light.diffuse = saved[:4]
            scale.forcewidth, scale.contactwidth, scale.contactheight = saved[4:]
        self.arrow_geoms = add_force_arrows(self.renderer.scene, arrows)
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
