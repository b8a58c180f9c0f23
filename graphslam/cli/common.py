"""What every command shares: exit statuses and the summary-table formatting."""

from __future__ import annotations

import sys
from pathlib import Path

EXIT_OK = 0
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def summary_table(rows: list[tuple[str, object]]) -> str:
    """``(label, value)`` rows as an indented two-column table."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def fmt(value, spec: str) -> str:
    """``value`` formatted with ``spec``, or "n/a" when it is None."""
    return "n/a" if value is None else format(value, spec)


def report_outputs(summary: str, out_dir: Path, paths: dict, interrupted: bool) -> int:
    """Print a run's summary table and where its outputs went; the exit status."""
    print(summary)
    print(f"outputs in {out_dir}/: " + ", ".join(p.name for p in paths.values()))
    if interrupted:
        print("graphslam: interrupted; wrote the estimate so far", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK
