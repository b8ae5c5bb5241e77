"""``make bench``: every benchmark of the project, each printing its numbers as ratios against a baseline
measured in the same process. Results are also written to bench/out/results.json."""

from __future__ import annotations

import importlib
import json
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

BENCHES = (
    "bench_controller",
    "bench_cpp_core",
    "bench_collision_tick",
    "bench_detection_stage",
    "bench_isolation",
    "bench_realtime_loop",
    "bench_closed_loop",
    "bench_long_runs",
    "bench_replay",
    "bench_ident",
    "bench_ident_memory",
    "bench_sweeps",
    "bench_bags",
    "bench_ros",
)


def main() -> int:
    print(f"python {platform.python_version()} on {platform.machine()}, {platform.node()}")
    results: dict[str, object] = {}
    for name in BENCHES:
        if not (HERE / f"{name}.py").exists():
            continue
        print(f"\n=== {name} ===")
        t0 = time.perf_counter()
        mod = importlib.import_module(name)
        results[name] = mod.main()
        print(f"({name}: {time.perf_counter() - t0:.1f} s)")
    out = HERE / "out"
    out.mkdir(exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"\nwrote {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
