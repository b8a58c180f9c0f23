"""Output files: TUM trajectory, landmark CSV, metrics JSON (numpy + stdlib)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from slamcore.planar.records import Estimate


def write_tum(path: Path, stamps: np.ndarray, wTb: np.ndarray) -> None:
    """TUM format ``t x y z qx qy qz qw``; 2-D poses lie in z = 0, yaw about z.

    Args:
        stamps: (N,) seconds, or pose ids where the data has no timestamps.
        wTb: (N, 3) ``[x, y, theta]``.
    """
    half = 0.5 * wTb[:, 2]
    rows = np.column_stack([stamps, wTb[:, 0], wTb[:, 1], np.zeros(len(wTb)),
                            np.zeros(len(wTb)), np.zeros(len(wTb)), np.sin(half), np.cos(half)])
    with open(path, "w", encoding="utf-8") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for r in rows:
            stamp = f"{int(r[0])}" if float(r[0]).is_integer() else f"{r[0]:.6f}"
            f.write(stamp + " " + " ".join(f"{v:.9g}" for v in r[1:]) + "\n")


def write_landmarks_csv(path: Path, estimate: Estimate) -> None:
    """``id,x,y`` with ids as in the input (or the back end's own under unknown association)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write("id,x,y\n")
        for lid, (x, y) in zip(estimate.landmark_ids, estimate.landmarks_w):
            f.write(f"{int(lid)},{x:.9g},{y:.9g}\n")


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, data: dict) -> None:
    with open(path, "w", encoding="utf-8") as f:
        json.dump(_jsonable(data), f, indent=2, sort_keys=False)
        f.write("\n")
