"""Peak memory of ``reflexarm identify dynamics`` on long logs: read in blocks against read whole (issue 20
item 15: 1e7 rows took 9.6 GB read whole; the goal is < 2 GB).

A 7-joint log at 1 kHz (the Atlas arm of the robot files, a 10 s Fourier trajectory repeated, its torques from
the regressor and the file's friction, with torque and velocity noise) is generated in a temporary folder,
in pieces, as Parquet (default) or CSV. The command runs as a child process (``--method both`` with a
friction file, so both methods are identified; ``--no-projection``: the projection onto consistent
parameters costs the same at any length; ``--quiet``); its peak resident memory is the child's
own high-water mark (``VmHWM`` of ``/proc/self/status``, read by the child as it ends), its CPU time
``ru_utime + ru_stime`` from ``os.wait4``. Measured:

* **blocks**: the long log (default 1e7 rows) read in blocks (``--block-rows 100000``, the default);
* **whole, baseline**: a shorter log (default 1e6 rows) read whole (``--block-rows 0``), and the same
  shorter log in blocks: the ratio whole / blocks on it, and the bytes a row each path costs above the
  command's fixed memory (imports, robot), from the two lengths.

Run with ``make bench`` (short: 2e6 rows, as ``BENCH_IDENT_ROWS`` says) or
``python bench/bench_ident_memory.py --rows 10000000 [--format csv]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROBOT = "atlas_v5_left_arm"
TARGET_BYTES = 2 << 30
PIECE = 50_000  # rows generated at a time (the regressor of a piece: 50,000 x 7 x 70 x 8 B = 196 MB)


def write_log(path: Path, rows: int, fmt: str, seed: int = 0) -> float:
    """Generate the log (see the module docstring) in pieces; returns its size [bytes]."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from reflexarm.ident import BatchRegressor, FrictionParameters
    from reflexarm.ident.excitation.design import FourierTrajectory
    from reflexarm.robots import load_robot

    robot = load_robot(ROBOT)
    rng = np.random.default_rng(seed)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), robot.home)
    reg, fr, params = BatchRegressor(robot), FrictionParameters.from_model(robot.friction), robot.inertial_parameters()
    names = ["t"] + [f"{s}_{j + 1}" for s in ("q", "dq", "tau") for j in range(7)]
    writer = None
    for k0 in range(0, rows, PIECE):
        t = 1e-3 * np.arange(k0, min(k0 + PIECE, rows))
        q, dq, ddq = tr.evaluate(t)
        tau = reg.compute_regressor(q, dq, ddq) @ params + fr.compute_torque(dq) + 0.05 * rng.normal(size=q.shape)
        dq = dq + 0.01 * rng.normal(size=dq.shape)
        cols = np.column_stack([t, q, dq, tau])
        if fmt == "parquet":
            table = pa.table({n: cols[:, i] for i, n in enumerate(names)})
            writer = writer or pq.ParquetWriter(path, table.schema)
            writer.write_table(table)
        else:
            with path.open("a") as fh:
                if k0 == 0:
                    fh.write(",".join(names) + "\n")
                np.savetxt(fh, cols, fmt="%.10g", delimiter=",")
    if writer is not None:
        writer.close()
    return path.stat().st_size


def run_cli(log: Path, block_rows: int, out: Path, friction: Path) -> dict[str, float]:
    """Peak RSS [bytes], CPU and wall time [s] of one ``identify dynamics`` child process."""
    argv = ["identify", "dynamics", "--robot", ROBOT, "--log", str(log), "--friction", str(friction),
            "--block-rows", str(block_rows), "--no-projection", "--out", str(out), "--quiet"]  # fmt: skip
    hwm = out.with_suffix(".hwm")
    cmd = [sys.executable, "-c", _CHILD, str(hwm), *argv]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{err[-2000:]}")
    return {"peak_rss": float(hwm.read_text()), "cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall}


#: The child: the command, then its peak resident memory (VmHWM of /proc/self/status: the high-water mark of
#: this process's own memory; ru_maxrss is not used, Linux carries the parent's RSS at fork into it).
_CHILD = """
import sys
from reflexarm.cli import main
code = main(sys.argv[2:])
kb = next(line.split()[1] for line in open("/proc/self/status") if line.startswith("VmHWM:"))
open(sys.argv[1], "w").write(str(int(kb) * 1024))
sys.exit(code)
"""


def _models(out: Path) -> dict[str, np.ndarray]:
    return {
        m: np.asarray(json.loads((out / f"model_{m}.json").read_text())["identification"]["beta_b"])
        for m in ("combined", "sequential")
    }


def main(rows: int | None = None, small: int | None = None, fmt: str = "parquet") -> dict[str, object]:
    rows = rows or int(os.environ.get("BENCH_IDENT_ROWS", 2_000_000))
    small = small or min(rows // 2, 1_000_000)
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} cores (wall times rise with it; CPU times much less)")
    results: dict[str, object] = {"rows": rows, "small_rows": small, "format": fmt, "load_average": load}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        friction = root / "friction.json"
        from reflexarm.ident import FrictionParameters
        from reflexarm.robots import load_robot

        friction.write_text(json.dumps(FrictionParameters.from_model(load_robot(ROBOT).friction).to_dict()))
        runs = {}
        for name, n, block in (
            ("small_whole", small, 0),
            ("small_blocks", small, 100_000),
            ("long_blocks", rows, 100_000),
        ):
            log = root / f"log_{n}.{fmt}"
            if not log.exists():
                t0 = time.perf_counter()
                size = write_log(log, n, fmt)
                print(f"generated {n:,} rows ({size / 2**20:,.0f} MB {fmt}) in {time.perf_counter() - t0:.0f} s")
                results[f"size_{n}"] = size
            runs[name] = run_cli(log, block, root / name, friction)
            r = runs[name]
            print(f"{name:>13}: {n:>11,} rows, peak RSS {r['peak_rss'] / 2**20:7,.0f} MB, CPU {r['cpu_s']:6.1f} s, "
                  f"wall {r['wall_s']:6.1f} s")  # fmt: skip
            if name == "small_blocks":
                a, b = _models(root / "small_whole"), _models(root / "small_blocks")
                for m in a:
                    rel = float(np.linalg.norm(b[m] - a[m]) / np.linalg.norm(a[m]))
                    print(f"  {m}: |beta_b(blocks) - beta_b(whole)| / |beta_b(whole)| = {rel:.2g}")
                    results[f"beta_rel_{m}"] = rel
        results.update(runs)
    whole, blocks, long = runs["small_whole"], runs["small_blocks"], runs["long_blocks"]
    per_row_blocks = (long["peak_rss"] - blocks["peak_rss"]) / max(rows - small, 1)
    print(f"{small:,} rows: whole / blocks peak RSS = {whole['peak_rss'] / blocks['peak_rss']:.2f}, CPU "
          f"{whole['cpu_s'] / blocks['cpu_s']:.2f}")  # fmt: skip
    goal = "below" if long["peak_rss"] < TARGET_BYTES else "ABOVE"
    print(f"blocks: {per_row_blocks:.1f} bytes of peak RSS a row beyond {small:,} rows; {rows:,} rows: "
          f"{long['peak_rss'] / 2**30:.2f} GB ({goal} the 2 GB goal)")  # fmt: skip
    results["bytes_per_row_blocks"] = per_row_blocks
    return results


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rows", type=int, default=10_000_000)
    p.add_argument("--small", type=int, default=None)
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    a = p.parse_args()
    main(a.rows, a.small, a.format)
