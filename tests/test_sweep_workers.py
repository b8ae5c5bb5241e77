"""A sweep's local workers die with the sweep's process (issue 20 item 17): after ``kill -9`` of a sweep
with two workers busy in their runs, no worker process is left (with joblib's loky pool, 4 were still
alive 30 s later). Linux only: the kernel's parent-death signal is what makes it hold for SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")

#: How long the test waits for things that take well under a second (process start-up of spawned workers
#: importing numpy and reflexarm, the kernel delivering a signal). Generous for a loaded 2-core machine: this
#: is a deadline for a condition, not a timing measurement.
DEADLINE = 60.0

SCRIPT = """
import os, sys, time
from pathlib import Path
from reflexarm.experiments.sweeps import SweepTask, run_sweep

OUT = Path(sys.argv[1])

def busy(task, ctx):
    (OUT / f"pid-{os.getpid()}").write_text("")
    time.sleep(600)
    return {"x": 1.0}

if __name__ == "__main__":
    tasks = [SweepTask("k", float(i), "c", i) for i in range(6)]
    run_sweep(tasks, busy, OUT / "sweep", workers=2, progress=False)
"""


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie (an orphan's zombie waits for a reaper that may be slow)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    state = next((line.split()[1] for line in status.splitlines() if line.startswith("State:")), "X")
    return state not in ("Z", "X")


def _wait_for(condition, what: str) -> None:
    end = time.monotonic() + DEADLINE
    while not condition():
        if time.monotonic() > end:
            pytest.fail(f"{what} within {DEADLINE:g} s")
        time.sleep(0.1)


def test_workers_die_with_a_killed_sweep(tmp_path):
    script = tmp_path / "sweep_script.py"
    script.write_text(SCRIPT)
    parent = subprocess.Popen([sys.executable, str(script), str(tmp_path)], cwd=tmp_path)
    try:
        _wait_for(lambda: len(list(tmp_path.glob("pid-*"))) == 2 or parent.poll() is not None, "two busy workers")
        assert parent.poll() is None, f"the sweep ended on its own (exit {parent.returncode})"
        workers = [int(p.name.removeprefix("pid-")) for p in tmp_path.glob("pid-*")]
        assert all(_alive(w) for w in workers) and parent.pid not in workers
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        _wait_for(lambda: not any(_alive(w) for w in workers), f"workers {workers} gone after kill -9 of the sweep")
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for p in tmp_path.glob("pid-*"):  # never leave a worker behind, whatever failed
            pid = int(p.name.removeprefix("pid-"))
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
