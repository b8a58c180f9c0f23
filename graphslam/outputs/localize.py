"""``localize.csv``: one row per frame of ``graphslam localize`` (numpy + stdlib).

Columns: ``frame`` (index in the sequence), ``t`` (seconds, or the frame index
where the sequence has no stamps), ``status`` (``tracked``, ``relocalised`` or
``lost``), the pose ``x y z qx qy qz qw`` (camera in the map's world frame,
metres; empty when lost) and its covariance as the 21 upper-triangle entries
``c_ij`` (``i <= j``) of the (6, 6) matrix in the order ``[rho (m), phi
(rad)]``, perturbation on the right (empty when lost).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphslam.outputs.writers import seconds, stamp_texts
from slamcore.files import atomic_open
from slamcore.spatial.geometry import rotation_to_quaternion

_UPPER = np.triu_indices(6)
HEADER = "frame,t,status,x,y,z,qx,qy,qz,qw," + ",".join(f"c{i}{j}" for i, j in zip(*_UPPER, strict=True))


def write_localize_csv(path: Path, frames, stamps, statuses, poses, covariances) -> None:
    """One row per frame (module docstring); ``poses``/``covariances`` entries may be None."""
    stamps = np.asarray(stamps, dtype=float)
    whole = bool(np.all(stamps == np.round(stamps)))  # frame indices, not seconds
    texts = [f"{int(t)}" for t in stamps] if whole else stamp_texts(stamps, seconds)
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write(HEADER + "\n")
        for frame, stamp, status, T, C in zip(frames, texts, statuses, poses, covariances, strict=True):
            row = [str(int(frame)), stamp, status]
            if T is None:
                row += [""] * (7 + len(_UPPER[0]))
            else:
                q = rotation_to_quaternion(np.asarray(T)[None, :3, :3])[0]
                row += [f"{v:.9g}" for v in (*np.asarray(T)[:3, 3], *q)]
                row += [f"{v:.6g}" for v in np.asarray(C)[_UPPER]]
            f.write(",".join(row) + "\n")
