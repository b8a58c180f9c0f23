"""What every command shares: exit statuses, the summary-table formatting and the
Rerun sink checks (a viewer that cannot be used becomes a saved recording)."""

from __future__ import annotations

import sys
from pathlib import Path

from slamcore.errors import GraphSlamError

EXIT_OK = 0
#: Some of the work failed; what succeeded is written (``compare``).
EXIT_FAILED = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def summary_table(rows: list[tuple[str, object]]) -> str:
    """``(label, value)`` rows as an indented two-column table."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def fmt(value, spec: str) -> str:
    """``value`` formatted with ``spec``, or "n/a" when it is None."""
    return "n/a" if value is None else format(value, spec)


def recoveries_text(recoveries: dict[str, int]) -> str:
    """The non-zero numerical recovery counts, e.g. ``"damped_update 3, noise_floor 1"``."""
    return ", ".join(f"{k} {v}" for k, v in recoveries.items() if v)


def report_outputs(summary: str, out_dir: Path, paths: dict, interrupted: bool) -> int:
    """Print a run's summary table and where its outputs went; the exit status."""
    print(summary)
    print(f"outputs in {out_dir}/: " + ", ".join(p.name for p in paths.values()))
    if interrupted:
        from graphslam.pipelines.common import active_guard

        guard = active_guard()
        name = "" if guard is None else f" ({guard.signal_name})"
        print(f"graphslam: interrupted{name}; wrote the estimate so far", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK


def warn(message: str) -> None:
    """One ``graphslam: warning:`` line on stderr."""
    print(f"graphslam: warning: {message}", file=sys.stderr, flush=True)


def check_rerun_flags(args) -> None:
    """Refuse Rerun flags that would do nothing, and a malformed ``--rerun-url``,
    before any work."""
    from graphslam.visualisation.recording import parse_viewer_url
    from slamcore.errors import ConfigError

    if args.rerun_url is not None:
        if args.rerun != "connect":
            raise ConfigError("--rerun-url applies to --rerun connect only")
        parse_viewer_url(args.rerun_url)
    every = getattr(args, "rerun_every", None)
    if every is not None:
        if args.rerun == "off":
            raise ConfigError("--rerun-every applies only when a recording is made "
                              "(not with --rerun off)")
        if every < 1:
            raise ConfigError("--rerun-every must be at least 1")


def rerun_sink(mode: str, url: str | None, file_name: str) -> str:
    """The stream a run will use: ``mode``, or "save" (after one warning line)
    when the viewer to spawn or connect to cannot be used."""
    from graphslam.visualisation.recording import sink_problem

    problem = sink_problem(mode, url)
    if problem is None:
        return mode
    warn(f"{problem}; saving {file_name} in the output folder instead")
    return "save"


def open_recorder(open_fn, mode: str, path: Path, url: str | None):
    """``(recorder, mode used)``: ``open_fn(mode, path, url)``, falling back to
    saving ``path`` when the viewer fails to start after all."""
    from graphslam.visualisation.recording import ViewerUnavailable

    try:
        return open_fn(mode, path, url), mode
    except (ViewerUnavailable, GraphSlamError) as e:
        warn(f"{e}; saving {path.name} instead")
        return open_fn("save", path, None), "save"


def close_recorder(recorder) -> bool:
    """Close a recorder; a viewer that stopped taking the stream, or a recording
    process that failed, is a warning (the run's files are written by then, and the
    steps after this one -- the map, the summary -- must still run). Returns
    whether the recording was closed whole."""
    from graphslam.visualisation.recording import ViewerUnavailable

    try:
        recorder.close()
    except (ViewerUnavailable, GraphSlamError) as e:
        warn(str(e))
        return False
    return True
