"""What every closed-loop command writes besides its own numbers: a still of the scene, videos on request,
traces and JSON summaries, in one place.

``add_output_options(parser)`` adds ``--video``, ``--fps`` and ``--frame-size``. A command wraps its runs
in ``with SceneCapture(args, out, "name") as scene:``; every closed-loop run inside gets a
:class:`~reflexarm.sim.video.StillCapture` and, with ``--video``, a
:class:`~reflexarm.sim.video.VideoRecorder` (through :func:`~reflexarm.sim.run_observers.observing_runs`,
so experiment functions need no extra argument). ``scene.finish(run_names, summary=path)`` then writes
``<name>_still.png`` (the first run with contact, at its largest external torque; else the first run's
start), names the videos ``<name>_<run>.mp4`` and records both in the JSON summary under ``"scene"``.

The collision event (issue 15) is drawn from each run's trace, known only after the run: ``finish`` also
writes ``<name>_event.png``, the first run with a detection at its detecting tick with the estimated contact
force beside the true one (:meth:`~reflexarm.sim.video.StillCapture.save_event`), and the videos render their
frames then (deferred), with the event drawn from detection on. The traces are given as ``traces=`` or read
from the files :func:`write_traces` wrote beside them (``<name>_<slug(run)>.npz``).
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reflexarm.errors import ConfigError

if TYPE_CHECKING:
    from types import TracebackType

    from reflexarm.signals import Command, Measurement
    from reflexarm.sim import Plant, Trace
    from reflexarm.sim.run_observers import CompiledStill
    from reflexarm.sim.video import StillCapture, VideoRecorder

__all__ = [
    "SceneCapture",
    "add_output_options",
    "fault_line",
    "fault_record",
    "frame_size",
    "number_joints",
    "slug",
    "write_json",
    "write_traces",
]

DEFAULT_FRAME_SIZE = "640x480"


def add_output_options(p: argparse.ArgumentParser) -> None:
    """``--video``, ``--fps`` and ``--frame-size`` (the still of the scene is always written)."""
    g = p.add_argument_group("scene pictures (a still of the scene at contact is always written)")
    g.add_argument(
        "--video",
        action="store_true",
        help="also render every closed-loop run to an MP4 in the output folder (H.264; needs the optional extra: "
        "pip install reflexarm[video])",
    )
    g.add_argument("--fps", type=float, default=30.0, help="video frames per simulated second (default 30)")
    g.add_argument(
        "--frame-size",
        default=DEFAULT_FRAME_SIZE,
        metavar="WxH",
        help=f"size of the still and the video frames [px], multiples of 16 (default {DEFAULT_FRAME_SIZE})",
    )


def frame_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); anything else is a :class:`ConfigError` naming the value."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if m is None:
        raise ConfigError(f"--frame-size expects WIDTHxHEIGHT in pixels (e.g. {DEFAULT_FRAME_SIZE}); got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if w < 16 or h < 16 or w % 16 or h % 16:
        raise ConfigError(
            f"--frame-size must be multiples of 16 pixels (H.264 macroblocks), e.g. {DEFAULT_FRAME_SIZE}; got {text!r}"
        )
    return w, h


def slug(name: str) -> str:
    """A file-name-safe form of a run name: ``"DC+EFC"`` -> ``"dc_plus_efc"``, ``"stiff/ee_force"`` ->
    ``"stiff_ee_force"``."""
    s = name.strip().lower().replace("+", "_plus_")
    s = re.sub(r"[^a-z0-9]+", "_", s)
    return re.sub(r"_+", "_", s).strip("_") or "run"


def _jsonable(x: object) -> object:
    import numpy as np

    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serializable: {type(x).__name__}")


def write_json(path: Path, doc: object) -> Path:
    """``doc`` as indented JSON (numpy values converted)."""
    path.write_text(json.dumps(doc, indent=2, default=_jsonable))
    return path


def write_traces(out: Path, prefix: str, traces: Mapping[str, Trace]) -> list[Path]:
    """Each trace as ``<out>/<prefix>_<slug(name)>.npz``; returns the paths."""
    paths = []
    for name, tr in traces.items():
        path = out / f"{prefix}_{slug(name)}.npz"
        tr.save(path)
        paths.append(path)
    return paths


def fault_record(trace: Trace) -> dict[str, Any] | None:
    """The controller's fault in a run: when it first faulted [s], the ticks in fault and the first fault's text;
    None if it never did. A run whose controller faulted is the fault's safe command from then on, not the
    experiment: the commands print it beside their table (and write it into their summary)."""
    import numpy as np

    faulted = np.flatnonzero(np.asarray(trace.fault) != "")
    if faulted.size == 0:
        return None
    k = int(faulted[0])
    return {"first_s": float(trace.t[k]), "ticks": int(faulted.size), "text": str(trace.fault[k])}


def fault_line(run: str, fault: dict[str, Any]) -> str:
    """One line for :func:`fault_record`'s record."""
    return (
        f"[{run}] the controller FAULTED at t = {fault['first_s']:.3f} s ({fault['ticks']} ticks in fault): "
        f"{fault['text']}; the run after it is the fault's safe command, not the experiment"
    )


def number_joints(row: dict[str, Any], joint_names: Sequence[str], key: str = "detected_joints") -> dict[str, Any]:
    """``row`` with the 0-based joint indices under ``key`` made 1-based (as joints are numbered in every
    flag and printed line) and their names beside them (``<key minus 's'>_names``, e.g.
    ``detected_joint_names``). The Python summaries stay 0-based (array indices); command-line summaries
    are for people."""
    out = dict(row)
    joints = out.get(key)
    if isinstance(joints, (list, tuple)):
        out[key] = [int(j) + 1 for j in joints]
        out[f"{key.removesuffix('s')}_names"] = [joint_names[int(j)] for j in joints]
    return out


class _RunObserver:
    """The still and (optionally) the video of one run."""

    def __init__(self, still: StillCapture, video: VideoRecorder | None) -> None:
        self.still, self.video = still, video

    def __call__(self, k: int, plant: Plant, m: Measurement, cmd: Command) -> None:
        self.still(k, plant, m, cmd)
        if self.video is not None:
            self.video(k, plant, m, cmd)

    @property
    def accepts_compiled(self) -> bool:
        """A compiled run may hand over its recorded still states; a video needs the Python loop."""
        return self.video is None

    def take_compiled(self, plant: Plant, record: CompiledStill) -> None:
        self.still.take_compiled(plant, record)


class SceneCapture:
    """Stills (always) and videos (``--video``) of the closed-loop runs of one command.

    Args:
        args: the parsed options of :func:`add_output_options` (``video``, ``fps``, ``frame_size``).
        out: the output folder.
        name: prefix of the files (``<name>_still.png``, ``<name>_<run>.mp4``).

    Raises:
        ConfigError: a bad ``--frame-size``/``--fps``, or ``--video`` without imageio/imageio-ffmpeg
            (raised here, before any run starts).
    """

    def __init__(self, args: argparse.Namespace, out: Path, name: str) -> None:
        from reflexarm.sim.video import _import_imageio

        self.out, self.name = Path(out), name
        self.width, self.height = frame_size(getattr(args, "frame_size", DEFAULT_FRAME_SIZE))
        self.video = bool(getattr(args, "video", False))
        self.fps = float(getattr(args, "fps", 30.0))
        if self.video:
            if not self.fps > 0:
                raise ConfigError(f"--fps must be a positive number of frames per second; got {self.fps:g}")
            _import_imageio()  # fail now, not after the runs
        self.runs: list[_RunObserver] = []
        self._context: Any = None

    def _observe(self, plant: Plant) -> _RunObserver:
        from reflexarm.sim.video import StillCapture, VideoRecorder

        video = None
        if self.video:
            path = self.out / f"{self.name}_run{len(self.runs) + 1}.mp4"
            video = VideoRecorder(path, fps=self.fps, width=self.width, height=self.height, defer=True)
        run = _RunObserver(StillCapture(), video)
        self.runs.append(run)
        return run

    def __enter__(self) -> SceneCapture:
        from reflexarm.sim.run_observers import observing_runs

        self._context = observing_runs(self._observe)
        self._context.__enter__()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        try:
            if exc_type is not None:  # no finish() will come: write the videos without the event
                self._close_videos()
        finally:
            if self._context is not None:
                self._context.__exit__(exc_type, exc, tb)
                self._context = None

    def _close_videos(self) -> None:
        for run in self.runs:
            if run.video is not None:
                run.video.close()

    def _traces(self, names: list[str] | None, traces: Sequence[Trace] | None) -> list[Trace | None]:
        """One trace per run: ``traces`` when it has one per run, else the files written beside (or None)."""
        from reflexarm.sim import Trace

        if traces is not None and len(traces) == len(self.runs):
            return list(traces)
        found: list[Trace | None] = []
        for i in range(len(self.runs)):
            path = self.out / f"{self.name}_{slug(names[i])}.npz" if names else None
            try:
                found.append(Trace.load(path) if path is not None and path.is_file() else None)
            except Exception:  # an unreadable file: no event for that run, never a failed command
                found.append(None)
        return found

    def _event_still(self, names: list[str] | None, traces: list[Trace | None]) -> dict[str, Any] | None:
        """``<name>_event.png`` of the first run with a detection (None when no run has one)."""
        for i, (run, tr) in enumerate(zip(self.runs, traces, strict=True)):
            if tr is None or not tr.meta.get("collision_event"):
                continue
            path = self.out / f"{self.name}_event.png"
            try:
                info = run.still.save_event(path, tr, width=self.width, height=self.height)
            except Exception as e:  # a still never fails a command
                info = {"file": None, "notes": [f"the event still could not be drawn ({type(e).__name__}: {e})"]}
            info["run"] = names[i] if names else i + 1
            return info
        return None

    def finish(
        self,
        run_names: Sequence[str] | None = None,
        *,
        summary: Path | None = None,
        traces: Sequence[Trace] | None = None,
    ) -> dict[str, Any]:
        """Write the still (and the event still), name the videos after ``run_names`` (when there is one name
        per run), and add ``{"still": ..., "event_still": ..., "videos": [...]}`` under ``"scene"`` to the
        JSON ``summary`` file when it holds an object (else write it to ``<name>_scene.json``).

        Args:
            run_names: one name per run (file names of the videos; the traces' files).
            summary: the command's JSON summary.
            traces: the runs' traces, one per run, for the collision event (default: read from
                ``<name>_<slug(run)>.npz`` beside, when written).

        Returns:
            The ``"scene"`` record (``still``: file, moment, t, run; ``event_still``: file, t, t_detect,
            arrows, notes, run, or None without a detection; ``videos``: file names, frames).
        """
        names = list(run_names) if run_names is not None and len(run_names) == len(self.runs) else None
        run_traces = self._traces(names, traces)
        for run, tr in zip(self.runs, run_traces, strict=True):
            if run.video is not None and tr is not None:
                run.video.annotate(tr)
        self._close_videos()
        record: dict[str, Any] = {"still": None, "event_still": None, "videos": []}
        if self.runs:
            with_contact = [i for i, r in enumerate(self.runs) if r.still.contact]
            i = with_contact[0] if with_contact else 0
            try:
                path = self.out / f"{self.name}_still.png"
                info = self.runs[i].still.save(path, width=self.width, height=self.height)
            except Exception as e:  # a still never fails a command (no GL context, a scene it cannot frame, ...)
                info = {"file": None, "notes": [f"the still could not be drawn ({type(e).__name__}: {e})"]}
            info["run"] = names[i] if names else i + 1
            record["still"] = info
            record["event_still"] = self._event_still(names, run_traces)
        for i, run in enumerate(self.runs):
            if run.video is None or run.video.frames == 0:
                continue
            path = run.video.path
            if names:
                target = self.out / f"{self.name}_{slug(names[i])}.mp4"
                path = path.replace(target)
            video: dict[str, Any] = {"file": path.name, "run": names[i] if names else i + 1, "frames": run.video.frames}
            if run.video.event_frames:  # frames with the collision event drawn (from detection on)
                video["event_frames"] = run.video.event_frames
            record["videos"].append(video)
        doc = json.loads(summary.read_text()) if summary is not None and summary.is_file() else None
        if summary is not None and isinstance(doc, dict):
            doc["scene"] = record
            write_json(summary, doc)
        else:  # no summary, or a list of rows (the collision experiments): beside it
            write_json(self.out / f"{self.name}_scene.json", record)
        return record

    @staticmethod
    def describe(record: Mapping[str, Any]) -> str:
        """One line for the console: what the still shows and how many videos were written."""
        still = record.get("still")
        if not still:
            return "no closed-loop run: no still"
        if still.get("file") is None:
            return "no still: " + "; ".join(still.get("notes", []))
        text = f"still of the scene: {still['file']} ({still['moment']}, t = {still['t']:.3f} s, run {still['run']})"
        event = record.get("event_still")
        if event and event.get("file"):
            drawn = ", ".join(a["label"] for a in event.get("arrows", [])) or "no arrow"
            text += f"; event at detection: {event['file']} (run {event['run']}: {drawn})"
        videos = record.get("videos") or []
        if videos:
            text += f"; videos: {', '.join(v['file'] for v in videos)}"
        return text
