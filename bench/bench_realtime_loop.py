"""The C++ example's 1 kHz loop (examples/cpp/realtime_loop.cpp): the tick's p99 against its median (issue 10:
p99 <= 2x median), and no heap allocation inside ``update()``.

Builds the example with ``cpp/build.sh`` when it is missing (the C++ library, its ctest and the example: a few
minutes once; incremental afterwards), then runs it twice on the built-in Atlas arm against its MuJoCo plant:
as a periodic loop that sleeps until each 1 ms deadline (what a real-time thread does) and with the ticks back to
back (``--busy``, which also times the bare Pinocchio calls of a tick in C++). Both medians and p99s come from the
same run, so the ratio does not depend on how fast this machine is; it does depend on how quiet it is: a
process on the other core, or a shared virtual machine, shows up in the p99 of the sleeping loop first. The p99/median
of the ticks that run no part of the modal damping (the same work every tick) is printed beside it: where that is
as large, the tail is the machine's wake-up after each sleep, not the tick's work. ``--dump FILE`` of the example
writes every tick's time for a closer look.

    python bench/bench_realtime_loop.py [--seconds 3]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "cpp" / "build" / "example" / "realtime_loop"
SOURCES = [ROOT / "examples" / "cpp" / "realtime_loop.cpp", *sorted((ROOT / "cpp").glob("src/*.cpp")),
           *sorted((ROOT / "cpp").glob("include/reflexarm/*.hpp"))]  # fmt: skip

_LINE = re.compile(r"update\(\): median ([\d.]+) us, p99 ([\d.]+) us, max ([\d.]+) us")
_ALLOC = re.compile(r"heap allocations inside update\(\): (\d+)")
_FLOOR = re.compile(r"update\(\)/calls ([\d.]+)")
_PLAIN = re.compile(r"ticks with no damping work \(\d+\): median ([\d.]+) us, p99 ([\d.]+) us")


def ensure_built() -> None:
    """Build (or bring up to date) the example with cpp/build.sh when a source is newer than the binary."""
    if EXAMPLE.exists() and all(p.stat().st_mtime <= EXAMPLE.stat().st_mtime for p in SOURCES):
        return
    print("building the C++ library and example (cpp/build.sh) ...", flush=True)
    res = subprocess.run(["bash", str(ROOT / "cpp" / "build.sh")], capture_output=True, text=True)
    if res.returncode != 0:
        sys.stderr.write(res.stdout[-3000:] + res.stderr[-3000:])
        raise RuntimeError(f"cpp/build.sh failed (exit {res.returncode}); its output is above")


def run(seconds: float, *flags: str) -> dict[str, float]:
    """One run of the example; its median/p99/max [us], allocations, and (with --busy) update()/calls."""
    res = subprocess.run([str(EXAMPLE), "", str(seconds), *flags], capture_output=True, text=True)
    out = res.stdout
    m, a = _LINE.search(out), _ALLOC.search(out)
    if res.returncode != 0 or m is None or a is None:
        raise RuntimeError(f"realtime_loop {' '.join(flags)} failed (exit {res.returncode}):\n{out}\n{res.stderr}")
    median, p99, worst = (float(x) for x in m.groups())
    row = {"median_us": median, "p99_us": p99, "max_us": worst, "p99_over_median": p99 / median,
           "allocations": float(a.group(1))}  # fmt: skip
    plain = _PLAIN.search(out)
    if plain is not None:  # the ticks that run no part of the modal damping: the same work every tick
        row["plain_p99_over_median"] = float(plain.group(2)) / float(plain.group(1))
    f = _FLOOR.search(out)
    if f is not None:
        row["update_over_calls"] = float(f.group(1))
    return row


def main(seconds: float = 3.0) -> dict[str, object]:
    ensure_built()
    results: dict[str, object] = {}
    print(f"examples/cpp/realtime_loop, Atlas arm, {seconds:g} s at 1 kHz against its MuJoCo plant")
    print(f"{'loop':<28}{'median':>10}{'p99':>10}{'max':>10}{'p99/median':>12}{'same, plain ticks':>19}"
          f"{'allocations':>13}")
    for name, flags in (("sleep to each deadline", ()), ("back to back (--busy)", ("--busy",))):
        row = run(seconds, *flags)
        results[name] = row
        print(f"{name:<28}{row['median_us']:>7.2f} us{row['p99_us']:>7.2f} us{row['max_us']:>7.1f} us"
              f"{row['p99_over_median']:>12.2f}{row.get('plain_p99_over_median', float('nan')):>19.2f}"
              f"{int(row['allocations']):>13d}")  # fmt: skip
        if "update_over_calls" in row:
            print(f"  update() / its bare Pinocchio calls inside C++: {row['update_over_calls']:.2f}")
    print("target: p99 <= 2x median; 0 allocations in update(). 'plain ticks': the ticks that run no part of the")
    print("modal damping (the same work every tick): a tail there comes from the machine, not from the tick's work")
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per run (default 3)")
    main(ap.parse_args().seconds)
