"""Precision and recall of place recognition against a ground truth of same-place pairs.

Ground truth (:func:`read_truth`), for the images of one folder in order:

- a CSV with a ``query,match`` header and one true pair per row (file names,
  either order);
- or an N x N image (PNG, ...) whose non-zero pixel (row i, column j) marks
  images i and j as the same place (the format of RTAB-Map's loop-closure
  samples); the diagonal is ignored.

Definitions (:func:`score`): a closure ``(q, m)`` is true when ``{q, m}`` is
a true pair; precision = true closures / closures (None without closures);
recall = the share of *queries with a true match* (images q with a true
pair ``{q, m}``, ``m < q``: an older image of the same place) that got a true
closure (None when the truth has no pair: there is nothing to recall, and 0
would read as every revisit missed).

The curve (:func:`pr_curve`) sweeps a threshold on the candidates' normalised
score over every verified candidate of a run made with no score threshold.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamcore.errors import InputError, quote
from slamcore.input_files import check_input_path

__all__ = ["read_truth", "restrict_truth", "score", "pr_curve", "PrPoint"]


@dataclass(frozen=True)
class PrPoint:
    """One point of a precision-recall curve (``threshold`` on the normalised score)."""

    threshold: float
    closures: int
    true: int
    precision: float | None
    recall: float | None


def _csv_truth(path: Path, names: dict[str, int]) -> set[tuple[int, int]]:
    pairs = set()
    with path.open(newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark
        rows = csv.reader(fh)
        header = next(rows, None)
        if header is None or [h.strip() for h in header[:2]] != ["query", "match"]:
            raise InputError("a truth CSV starts with the header query,match", path, 1)
        for line, row in enumerate(rows, start=2):
            if not row:
                continue
            if len(row) < 2:
                raise InputError("a row needs query,match", path, line)
            q, m = (Path(x.strip()).name for x in row[:2])
            for name in (q, m):
                if name not in names:
                    raise InputError(f"{quote(name)} is not an image of the folder", path, line)
            if names[q] == names[m]:  # a typo for another image, most likely: it scored nothing
                raise InputError(f"the row pairs {quote(q)} with itself (a pair is two images)", path, line)
            pairs.add((max(names[q], names[m]), min(names[q], names[m])))
    return pairs


def _image_truth(path: Path, n: int) -> set[tuple[int, int]]:
    from frontend.image import load_gray  # truncation checked, the file named

    try:
        img = load_gray(path)
    except InputError as e:
        raise InputError(f"cannot read the truth file as a CSV or an image ({e})", path) from None
    if img.shape != (n, n):
        raise InputError(
            f"truth image is {img.shape[1]}x{img.shape[0]}, the folder has {n} images (need {n}x{n})", path
        )
    i, j = np.nonzero(img)
    return {(int(max(a, b)), int(min(a, b))) for a, b in zip(i, j, strict=True) if a != b}


def restrict_truth(pairs: set[tuple[int, int]], index) -> tuple[set[tuple[int, int]], int]:
    """The pairs of a folder's truth among the images ``index`` (the folder's indices
    of a selection, in its order), as indices of the selection, and how many pairs were
    left out (an image of theirs not selected)."""
    at = {int(i): k for k, i in enumerate(index)}
    kept = {(max(at[a], at[b]), min(at[a], at[b])) for a, b in pairs if a in at and b in at}
    return kept, len(pairs) - len(kept)


def read_truth(path: str | Path, image_paths: list[Path]) -> set[tuple[int, int]]:
    """True same-place pairs as ``(later index, earlier index)`` (formats in the module docstring)."""
    path = Path(path)
    check_input_path(path, "truth file")
    names = {Path(p).name: i for i, p in enumerate(image_paths)}
    if path.suffix.lower() in (".csv", ".txt"):
        try:
            return _csv_truth(path, names)
        except UnicodeDecodeError as e:
            raise InputError(f"not a UTF-8 text file (byte {e.start}: {e.reason})", path) from None
        except (csv.Error, OSError) as e:  # a field over csv's limit, an I/O error
            raise InputError(f"cannot read the truth CSV: {e}", path) from None
    return _image_truth(path, len(image_paths))


def score(
    closures: list[tuple[int, int]], truth: set[tuple[int, int]]
) -> tuple[float | None, float | None, int]:
    """``(precision, recall, true closures)`` of ``(query, match)`` closures; precision
    None without closures, recall None without true pairs (module doc)."""
    queries = {q for q, _ in truth}
    true = [(q, m) for q, m in closures if (max(q, m), min(q, m)) in truth]
    precision = len(true) / len(closures) if closures else None
    recall = len({q for q, _ in true} & queries) / len(queries) if queries else None
    return precision, recall, len(true)


def pr_curve(verified: list[tuple[int, int, float]], truth: set[tuple[int, int]]) -> list[PrPoint]:
    """The curve over ``(query, match, normalised score)`` of verified candidates.

    One point per distinct score, from the highest (fewest closures) down: at
    threshold t the closures are the candidates with score >= t.
    """
    order = sorted(verified, key=lambda v: -v[2])
    points = []
    for k, (_, _, t) in enumerate(order):
        if k + 1 < len(order) and order[k + 1][2] == t:
            continue  # ties enter together
        chosen = [(q, m) for q, m, _ in order[: k + 1]]
        p, r, n_true = score(chosen, truth)
        points.append(PrPoint(float(t), len(chosen), n_true, p, r))
    return points
