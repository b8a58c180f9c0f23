"""Loop-closure outputs of ``graphslam loops`` and of a visual run: CSV and JSON lines."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from slamcore.files import atomic_open


def write_loops(closer, out_dir: Path, writes) -> dict[str, Path]:
    """``loops.csv`` (one row per closure added) and ``loops.jsonl`` (every candidate)
    of a :class:`graphslam.pipelines.loop_closing.VisualLoopCloser`, each through
    ``writes`` (:class:`graphslam.outputs.writers.OutputWrites`); the paths written."""
    paths: dict[str, Path] = {}
    writes(paths, "loops", out_dir / "loops.csv", _write_closures_csv, closer.records)
    writes(paths, "loops_log", out_dir / "loops.jsonl", closer.write_log)
    return paths


def _write_closures_csv(path: Path, records) -> None:
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "match", "score", "inliers", "pnp_inliers", "distance_m"])
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
