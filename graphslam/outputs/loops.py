"""Loop-closure outputs of ``graphslam loops`` and of a visual run: CSV and JSON lines."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from slamcore.files import atomic_open


def write_loops(closer, out_dir: Path, writes, files=None) -> dict[str, Path]:
    """``loops.csv`` (one row per closure added) and ``loops.jsonl`` (every candidate)
    of a :class:`graphslam.pipelines.loop_closing.VisualLoopCloser`, each through
    ``writes`` (:class:`graphslam.outputs.writers.OutputWrites`); the paths written.
    ``files``: (N,) each run frame's index in the files (``--frames`` moves them), given
    beside the run's ``query`` and ``match`` as ``query_file_frame``, ``match_file_frame``
    (pass 23: only the run's were written, the trajectory's times being the files')."""
    paths: dict[str, Path] = {}
    writes(paths, "loops", out_dir / "loops.csv", _write_closures_csv, closer.records, files)
    writes(paths, "loops_log", out_dir / "loops.jsonl", closer.write_log, files)
    return paths


def _file_frame(files, k) -> int | None:
    return None if k is None else int(k) if files is None else int(files[int(k)])


def _write_closures_csv(path: Path, records, files=None) -> None:
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "query",
                "match",
                "score",
                "inliers",
                "pnp_inliers",
                "distance_m",
                "query_file_frame",
                "match_file_frame",
            ]
        )
        for r in records:
            if r.accepted:
                w.writerow(
                    [
                        r.query,
                        r.match,
                        f"{r.detector.score:.6f}",
                        r.detector.n_inliers,
                        r.pnp.n_inliers,
                        f"{r.distance_m:.4f}",
                        _file_frame(files, r.query),
                        _file_frame(files, r.match),
                    ]
                )


def write_folder_loops_csv(path: Path, closures, paths: list[Path]) -> None:
    """``query,match,score,inliers`` (file names, the later image first) per accepted
    :class:`loopclosure.detector.DetectedLoop`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "match", "score", "inliers"])
        for c in closures:
            w.writerow([paths[c.query].name, paths[c.match].name, f"{c.score:.6f}", c.n_inliers])


def write_candidates_jsonl(path: Path, records, paths: list[Path]) -> None:
    """Every :class:`loopclosure.detector.CandidateRecord` as one JSON line, with file names."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "w", encoding="utf-8") as fh:
        for r in records:
            d = r.to_dict()
            d["query_name"] = paths[r.query].name
            d["match_name"] = None if r.match is None else paths[r.match].name
            fh.write(json.dumps(d) + "\n")
