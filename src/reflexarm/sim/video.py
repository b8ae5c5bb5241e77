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
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.sim._event_drawing import (
    EventDrawing,
    ForceArrow,
    detection_tick,
    event_drawing,
    rebuild_state,
    side_azimuth,
)
from reflexarm.sim._rendering import (
    DEFAULT_SIZE,
    CameraView,
    _check_size,
    _Painter,
    _status,
    frame_scene,
    render_frame,
)

if TYPE_CHECKING:
    from reflexarm.signals import Command, Measurement
    from reflexarm.sim.plant import Plant
    from reflexarm.sim.run_observers import CompiledStill
    from reflexarm.sim.trace import Trace

__all__ = [
    "CameraView",
    "EventDrawing",
    "ForceArrow",
    "StillCapture",
    "VideoRecorder",
    "frame_scene",
    "render_frame",
    "save_still",
]

#: What a still keeps of the plant: MuJoCo's integration state (time, qpos, qvel, mocap, applied forces).
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
#: The event still looks from this share of the framed distance, at a point this share of the way from the
#: contact to the framed centre: the arrows large, the arm and the scene object mostly in the picture.
EVENT_ZOOM = 0.6
#: Default video rate [frames per second of simulated time].
DEFAULT_FPS = 30.0
#: Below this |tau_ext| [Nm] on every joint nothing touches the arm: the still shows the start instead.
#: The true external torque is exactly 0 without contact or applied force; 1 mNm is far below any force
#: worth a picture and above round-off.
CONTACT_TORQUE = 1e-3


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
    joint torque (the norm |tau_ext| over the joints, :meth:`Plant.true_external_torque`): the moment the
    scene presses hardest on the arm. :meth:`save` renders the contact state when the peak reached
    :data:`CONTACT_TORQUE`, else the first tick. One capture per run; per tick it costs one evaluation of
    tau_ext and a sum of squares, and a copy of the state into a buffer when a new peak is reached.

    The criterion, to the bit (the compiled loop applies the same one in C++, ``reflexarm::StillStates``):
    s_k = sum over the joints of tau_ext_i^2, each square rounded, summed left to right from 0.0; tick k is
    the new peak when s_k > the largest s so far (starting at 0), so a tie keeps the earlier tick and a run
    without external torque has no peak. The state is taken when the callback is called at tick k: after
    the measurement and the command of tick k, before its physics step.

    A compiled run (:func:`~reflexarm.sim.compiled_loop.run_fast`) calls no callback per tick: it keeps
    these states in C++ and hands them over with :meth:`take_compiled` (``accepts_compiled`` is True).
    """

    #: A compiled run may hand over its recorded states (:mod:`reflexarm.sim.run_observers`).
    accepts_compiled = True

    def __init__(self) -> None:
        self.plant: Plant | None = None
        self.peak_torque = 0.0  #: largest |tau_ext| (norm over the joints) seen [Nm]
        self.peak_time: float | None = None  #: its time [s]
        self._start: np.ndarray | None = None
        self._peak: np.ndarray | None = None
        self._start_cmd: Command | None = None
        self._peak_cmd: Command | None = None
        self._buf = np.zeros(0)
        self._peak2 = 0.0

    def __call__(self, k: int, plant: Plant, measurement: Measurement, command: Command) -> None:
        if self.plant is None:
            self.plant, self._buf, self._peak2 = plant, np.zeros(plant.n), 0.0
            size = mujoco.mj_stateSize(plant.model, _STATE)
            self._start, self._peak = np.empty(size), np.empty(size)
            mujoco.mj_getState(plant.model, plant.data, self._start, _STATE)
            self._start_cmd = command
        peak2 = 0.0
        for x in plant.true_external_torque(out=self._buf).tolist():
            peak2 += x * x  # left to right, as the compiled loop sums (a BLAS dot may sum in another order)
        if peak2 > self._peak2:
            self._peak2, self.peak_torque, self.peak_time = peak2, math.sqrt(peak2), plant.time
            mujoco.mj_getState(plant.model, plant.data, self._peak, _STATE)
            self._peak_cmd = command

    def take_compiled(self, plant: Plant, record: CompiledStill) -> None:
        """Take the states a compiled run kept (instead of being called every tick); the same criterion.

        Raises:
            SimulationError: this capture has already seen a run, or the states were taken with another
                ``mjtState`` mask than this capture keeps.
        """
        if self.plant is not None:
            raise SimulationError("this StillCapture has already seen a run; one capture per run")
        if record.spec != int(_STATE):
            raise SimulationError(
                f"the compiled loop kept states with mjtState mask {record.spec}; a still needs {int(_STATE)} "
                "(mjSTATE_INTEGRATION)"
            )
        self.plant, self._buf = plant, np.zeros(plant.n)
        self._start, self._start_cmd = record.start_state.copy(), record.start_command
        self._peak = np.empty_like(self._start)
        if record.peak_tick is not None and record.peak_state is not None:
            self._peak2, self.peak_torque, self.peak_time = record.peak2, math.sqrt(record.peak2), record.peak_time
            self._peak[:] = record.peak_state
            self._peak_cmd = record.peak_command

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
        mujoco.mj_setState(plant.model, data, state, _STATE)
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

    def save_event(
        self,
        path: str | os.PathLike[str],
        trace: Trace,
        *,
        width: int = DEFAULT_SIZE[0],
        height: int = DEFAULT_SIZE[1],
    ) -> dict[str, Any]:
        """Render the run's collision event to a PNG: the scene at the detecting tick of ``trace`` (this
        capture's run) with the estimated contact force beside the true one and the event's text
        (:func:`~reflexarm.sim._event_drawing.event_drawing`).

        The state at detection is rebuilt from the kept state (contact, else start) and the trace (the arm's
        true q and dq, the recorded scene poses; :func:`~reflexarm.sim._event_drawing.rebuild_state`). A
        missing piece never fails the still: without a detection the kept moment is drawn, without an
        estimate or a truth its arrow is left out, and ``notes`` (also written in the picture) say why.

        Returns:
            ``file``, ``moment``, ``t``, ``t_detect`` (None without a detection), ``arrows`` (what was drawn:
            label, point [m], force [N]) and ``notes``.

        Raises:
            SimulationError: the capture has not seen a run.
        """
        if self.plant is None or self._start is None:
            raise SimulationError("no still to save: this StillCapture was not called by any run")
        width, height = _check_size(width, height)
        plant = self.plant
        state, cmd = (self._peak, self._peak_cmd) if self.contact else (self._start, self._start_cmd)
        base = mujoco.MjData(plant.model)
        mujoco.mj_setState(plant.model, base, state, _STATE)
        mujoco.mj_forward(plant.model, base)
        data, drawing, notes = base, None, []
        k = detection_tick(trace) if trace.n == plant.n else None
        if k is None:
            notes.append("no detection in this run: no event to draw")
        else:
            try:
                data = rebuild_state(plant, base, trace, k)
                drawing = event_drawing(trace, plant, k)
            except Exception as e:  # a still never fails a run
                data, drawing = base, None
                notes.append(f"the event could not be drawn ({type(e).__name__}: {e})")
        text = f"t = {float(data.time):6.3f} s"
        if drawing is not None:
            text += "\n" + drawing.text()
            notes += list(drawing.notes)
        elif cmd is not None:
            text = _status(plant, float(data.time), cmd)
        if notes and drawing is None:
            text += "\n" + "\n".join(notes)
        view = frame_scene(plant, data=data, aspect=width / height)
        if drawing is not None and drawing.arrows:
            # look across the force, so that the arrows show their length, and closer, at the contact
            view = frame_scene(plant, data=data, aspect=width / height, azimuth=side_azimuth(drawing, view.azimuth))
            at = np.mean([a.point for a in drawing.arrows], axis=0)
            centre = EVENT_ZOOM * np.asarray(view.lookat) + (1.0 - EVENT_ZOOM) * at
            lookat = (float(centre[0]), float(centre[1]), float(centre[2]))
            view = view._replace(lookat=lookat, distance=EVENT_ZOOM * view.distance)
        painter = _Painter(plant, width, height, view)
        try:
            image = painter.render(data, text, drawing.arrows if drawing is not None else ())
        finally:
            painter.close()
        out = _write_png(path, image)
        return {
            "file": out.name,
            "moment": "detection" if drawing is not None else ("contact" if self.contact else "start"),
            "t": float(data.time),
            "t_detect": None if drawing is None else drawing.t_detect,
            "arrows": [] if drawing is None else [_arrow_record(a) for a in drawing.arrows],
            "notes": notes,
        }


def _arrow_record(arrow: ForceArrow) -> dict[str, Any]:
    return {"label": arrow.label, "point_m": arrow.point.tolist(), "force_N": arrow.force.tolist()}


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
        defer: keep each frame's MuJoCo state and render the frames on :meth:`close`, so that the run's
            collision event, known only after the run, is drawn on the frames at and after detection
            (give the run's trace to :meth:`annotate` before closing). A few hundred floats per frame.

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
        defer: bool = False,
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
        self.defer = bool(defer)
        self._plant: Plant | None = None
        self._view: CameraView | None = camera
        self._pending: list[tuple[float, np.ndarray, str]] = []  # deferred frames: (t, state, text)
        self._trace: Trace | None = None
        self.event_frames = 0  #: frames written with the collision event drawn

    def __call__(self, k: int, plant: Plant, measurement: Measurement, command: Command) -> None:
        t = plant.time
        if self.defer:
            self._keep(plant, command)
            return
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

    def _keep(self, plant: Plant, command: Command) -> None:
        """A deferred frame: the state and the corner text, when a frame is due."""
        t = plant.time
        if self._plant is None:
            self._plant, self._t0 = plant, t
            self._view = self._view or frame_scene(plant, aspect=self.width / self.height)
        if t - self._t0 + 0.5 * plant.control_period < self.frames / self.fps:
            return
        state = np.empty(mujoco.mj_stateSize(plant.model, _STATE))
        mujoco.mj_getState(plant.model, plant.data, state, _STATE)
        self._pending.append((t, state, _status(plant, t, command) if self.overlay else ""))
        self.frames += 1

    def annotate(self, trace: Trace) -> None:
        """Draw ``trace``'s collision event (this recorder's run) on the deferred frames at and after its
        detection: the estimated force beside the true one, and the event's text."""
        self._trace = trace

    def _render_pending(self) -> None:
        plant, pending = self._plant, self._pending
        self._pending = []
        if plant is None or not pending:
            return
        trace = self._trace if self._trace is not None and self._trace.n == plant.n else None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        writer = self._imageio.get_writer(
            self.path, fps=self.fps, codec="libx264", pixelformat="yuv420p", macro_block_size=16
        )
        painter = _Painter(plant, self.width, self.height, self._view)
        data = mujoco.MjData(plant.model)
        try:
            for t, state, text in pending:
                mujoco.mj_setState(plant.model, data, state, _STATE)
                mujoco.mj_forward(plant.model, data)
                drawing = None
                if trace is not None:
                    k = int(np.argmin(np.abs(trace.t - t)))
                    try:
                        drawing = event_drawing(trace, plant, k)
                    except Exception as e:  # a frame never fails: draw it without the event
                        text += f"\nthe event could not be drawn ({type(e).__name__}: {e})"
                if drawing is not None:
                    text = (text + "\n" if self.overlay else "") + drawing.text()
                    self.event_frames += 1
                writer.append_data(painter.render(data, text, drawing.arrows if drawing is not None else ()))
        finally:
            writer.close()
            painter.close()

    def close(self) -> None:
        """Finish the file (idempotent); a deferred recorder renders its frames now."""
        if self.defer:
            self._render_pending()
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
