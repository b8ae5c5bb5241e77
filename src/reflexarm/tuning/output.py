"""What ``tune-thresholds`` writes: the proposal's table and file, and its figures (a module above the study and
its figures, so that neither reaches back to the other)."""

from __future__ import annotations

import json
from pathlib import Path

from reflexarm.tuning.study import ThresholdProposal

__all__ = ["write_thresholds"]


def write_thresholds(proposal: ThresholdProposal, out: str | Path, *, figure: bool = True) -> dict[str, Path]:
    """Write ``thresholds.json``, ``thresholds.csv`` and (``figure``) ``thresholds.png`` (residuals
    with both levels) and ``threshold_tails.png`` (rate against level per joint) into ``out``."""
    import pandas as pd

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    files = {"json": folder / "thresholds.json", "csv": folder / "thresholds.csv"}
    files["json"].write_text(json.dumps(proposal.as_dict(), indent=2))
    pd.DataFrame(proposal.rows()).to_csv(files["csv"], index=False, float_format="%.6g")
    if figure:
        from reflexarm.tuning.plots import plot_residual_levels, plot_tails

        files["figure"] = plot_residual_levels(proposal, folder / "thresholds.png")
        files["tails"] = plot_tails(proposal, folder / "threshold_tails.png")
    return files
