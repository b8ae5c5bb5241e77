"""Helpers shared by the command modules: common options, output folders, plain-text tables."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path


def add_common(p: argparse.ArgumentParser, *, default_out: str) -> None:
    """``--out DIR``, ``--seed N`` and ``--quiet`` (no progress bars)."""
    p.add_argument("--out", type=Path, default=Path(default_out), help=f"output folder (default {default_out})")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def out_dir(args: argparse.Namespace) -> Path:
    """Create and return the output folder named by ``--out``."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def format_table(rows: Sequence[dict[str, object]], columns: Sequence[tuple[str, str, str]]) -> str:
    """A fixed-width text table: ``columns`` are (key, header, format); None prints as '-'."""

    def cell(v: object, fmt: str) -> str:
        if v is None:
            return "-"
        try:
            return fmt.format(v)
        except (TypeError, ValueError):
            return str(v)

    body = [[cell(r.get(k), f) for k, _, f in columns] for r in rows]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, (_, h, _) in enumerate(columns)]
    lines = ["  ".join(h.rjust(w) for (_, h, _), w in zip(columns, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(b, widths, strict=True)) for b in body]
    return "\n".join(lines)
