"""What every closed-loop command writes (trace, summary, figure, still of the scene, video on request),
``reflexarm --version``, the top-level ``Controller`` and the 1-based joints of command-line summaries."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import matplotlib.image
import pytest

import reflexarm
from reflexarm._cli.run_outputs import SceneCapture, frame_size, number_joints, slug
from reflexarm.cli import main
from reflexarm.errors import ConfigError

#: (command line with short settings, trace glob, summary file, figure file, file prefix of the still)
COMMANDS = [
    pytest.param(
        ["simulate", "free-motion", "--duration", "0.5"],
        "free_motion_trace.parquet",
        "free_motion.json",
        "free_motion.png",
        "free_motion",
        id="free-motion",
    ),
    pytest.param(
        ["simulate", "velocity-tracking", "--travel", "0.4", "--speed", "0.4"],
        "velocity_tracking_*.npz",
        "velocity_tracking_summary.json",
        "fig5_velocity_tracking.png",
        "velocity_tracking",
        id="velocity-tracking",
    ),
    pytest.param(
        ["simulate", "link-collision"],
        "link_collision_*.npz",
        "link_collision_summary.json",
        "fig10_link_collision.png",
        "link_collision",
        marks=pytest.mark.slow,
        id="link-collision",
    ),
    pytest.param(
        ["demo"],
        "ee_collision_*.npz",
        "ee_collision_summary.json",
        "fig8_ee_collision.png",
        "ee_collision",
        marks=pytest.mark.slow,
        id="demo",
    ),
    pytest.param(
        ["simulate", "ee-collision"],
        "ee_collision_*.npz",
        "ee_collision_summary.json",
        "fig8_ee_collision.png",
        "ee_collision",
        marks=pytest.mark.slow,
        id="ee-collision",
    ),
    pytest.param(
        ["efc-step"],
        "efc_step_*.npz",
        "efc_step.json",
        "fig12_efc_step.png",
        "efc_step",
        marks=pytest.mark.slow,
        id="efc-step",
    ),
    pytest.param(
        ["compliance-loss", "--hand-stiffness", "1000"],
        "compliance_loss_*.npz",
        "compliance_loss.json",
        "fig11_hand_stiffness.png",
        "compliance_loss",
        marks=pytest.mark.slow,
        id="compliance-loss",
    ),
    pytest.param(
        ["mode-table"],
        "mode_table_*.npz",
        "mode_table.json",
        "fig3_mode_table.png",
        "mode_table",
        marks=pytest.mark.slow,
        id="mode-table",
    ),
]


@pytest.mark.parametrize(("command", "traces", "summary", "figure", "name"), COMMANDS)
def test_every_closed_loop_command_writes_trace_summary_figure_and_still(
    command, traces, summary, figure, name, tmp_path, capsys, monkeypatch
):
    out = tmp_path / "out"
    run_names: list[list[str]] = []
    finish = SceneCapture.finish

    def record_run_names(self, names=None, **kw):
        run_names.append(list(names or []))
        return finish(self, names, **kw)

    monkeypatch.setattr(SceneCapture, "finish", record_run_names)
    code = main([*command, "--out", str(out), "--quiet", "--frame-size", "320x240"])
    printed = capsys.readouterr().out
    assert code in (0, 1)  # mode-table: 1 when a measured mark disagrees with the paper's
    assert sorted(out.glob(traces)), f"no trace {traces} in {sorted(p.name for p in out.iterdir())}"
    if traces.endswith("_*.npz"):  # one trace per run, named as its video would be: <name>_<slug(run)>
        assert len(run_names) == 1
        assert sorted(p.stem for p in out.glob(traces)) == sorted(f"{name}_{slug(r)}" for r in run_names[0])
    assert (out / figure).is_file()
    still = out / f"{name}_still.png"
    assert matplotlib.image.imread(still).shape[:2] == (240, 320)
    doc = json.loads((out / summary).read_text())
    # the still is recorded in the summary (an object), or beside it (a list of rows)
    scene = doc["scene"] if isinstance(doc, dict) else json.loads((out / f"{name}_scene.json").read_text())
    assert scene["still"]["file"] == still.name
    assert scene["videos"] == []
    assert f"still of the scene: {still.name}" in printed


def test_video_option_writes_one_mp4_per_run(tmp_path, capsys):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "fm"
    argv = ["simulate", "free-motion", "--duration", "0.4", "--out", str(out), "--quiet", "--trace", "none"]
    assert main([*argv, "--video", "--fps", "10", "--frame-size", "160x128"]) == 0
    assert "videos: free_motion_free_motion.mp4" in capsys.readouterr().out
    doc = json.loads((out / "free_motion.json").read_text())
    assert doc["scene"]["videos"] == [{"file": "free_motion_free_motion.mp4", "run": "free motion", "frames": 4}]
    reader = imageio.get_reader(out / "free_motion_free_motion.mp4")
    assert sum(1 for _ in reader) == 4  # 0.4 s at 10 frames/s
    reader.close()
    assert not (out / "free_motion_trace.parquet").exists()  # --trace none


def test_frame_size_is_checked_before_any_run(tmp_path, capsys):
    assert frame_size("640x480") == (640, 480)
    assert frame_size(" 320 X 240 ") == (320, 240)
    with pytest.raises(ConfigError, match=r"--frame-size expects WIDTHxHEIGHT in pixels .*got 'big'"):
        frame_size("big")
    with pytest.raises(ConfigError, match=r"--frame-size must be multiples of 16 pixels .*got '650x480'"):
        frame_size("650x480")
    out = tmp_path / "o"
    assert main(["simulate", "free-motion", "--frame-size", "10x10", "--out", str(out), "--quiet"]) == 2
    assert "--frame-size must be multiples of 16 pixels (H.264 macroblocks), e.g. 640x480; got '10x10'" in (
        capsys.readouterr().err
    )
    assert not (out / "free_motion.json").exists()  # refused before the 60 s run, not after it


def test_run_names_become_file_names():
    assert slug("DC+EFC") == "dc_plus_efc"
    assert slug("Coll.Det") == "coll_det"
    assert slug("k1000/DC, no cut-off") == "k1000_dc_no_cut_off"
    assert slug("///") == "run"


def test_command_line_summaries_number_joints_from_one():
    names = ["shz", "shx", "ely"]
    row = {"detected_joints": [0, 2], "t": 1.0}
    assert number_joints(row, names) == {"detected_joints": [1, 3], "detected_joint_names": ["shz", "ely"], "t": 1.0}
    assert row["detected_joints"] == [0, 2]  # the Python row is left 0-based
    assert number_joints({"t": 1.0}, names) == {"t": 1.0}


def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"reflexarm {reflexarm.__version__}"


def test_controller_is_exported_and_imported_on_first_use():
    from reflexarm.control import Controller

    assert reflexarm.Controller is Controller
    assert "Controller" in reflexarm.__all__
    with pytest.raises(AttributeError, match="has no attribute 'Controler'"):
        _ = reflexarm.Controler  # type: ignore[attr-defined]
    code = "import sys, reflexarm; print('reflexarm.control' in sys.modules)"
    light = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert light.stdout.strip() == "False"


@pytest.mark.parametrize(
    ("env", "expected"),
    [({}, "egl"), ({"MUJOCO_GL": "glfw"}, "glfw"), ({"DISPLAY": ":0"}, None)],
    ids=["headless", "user-choice-kept", "display"],
)
def test_mujoco_gl_is_egl_on_a_headless_machine(env, expected):
    base = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    code = "import os, reflexarm; print(os.environ.get('MUJOCO_GL'))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**base, **env})
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == str(expected)


def test_a_still_that_cannot_be_drawn_never_fails_the_command(tmp_path, capsys, monkeypatch):
    """The still is a side product (issue 20 item 12): if drawing it fails (no GL context, a scene it cannot
    frame), the command still ends with its numbers written and says why there is no still."""
    from reflexarm.sim.video import StillCapture

    def broken(self, *args, **kwargs):
        raise RuntimeError("no OpenGL context on this machine")

    monkeypatch.setattr(StillCapture, "save", broken)
    out = tmp_path / "out"
    code = main(["simulate", "free-motion", "--duration", "0.2", "--out", str(out), "--quiet"])
    printed = capsys.readouterr().out
    assert code == 0
    assert not (out / "free_motion_still.png").exists()
    doc = json.loads((out / "free_motion.json").read_text())
    assert doc["scene"]["still"]["file"] is None
    assert "no OpenGL context on this machine" in doc["scene"]["still"]["notes"][0]
    assert "no still: the still could not be drawn (RuntimeError: no OpenGL context" in printed
