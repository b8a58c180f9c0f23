"""What made an output: the toolkit's own code, the libraries it ran on and how the
command was invoked (the ``provenance`` of metrics.json, compare.json, eval.json and
map.json; a sweep re-runs a run folder that other code made: :func:`code_identity`).

Computed once a process: hashing the toolkit's ``.py`` files (about 200 files, 2 MB)
takes about 50 ms cold, once per run or sweep.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import importlib.util
import platform
import sys
from pathlib import Path

#: The toolkit's importable packages: a change to any of their source files can change
#: a result, whatever the version number says (a working copy between releases).
PACKAGES = ("graphslam", "slamcore", "filters", "frontend", "loopclosure")
#: Distributions that install ``cv2`` (read from their metadata: importing cv2 only to
#: name its version costs a planar run about 0.1 s).
OPENCV_DISTRIBUTIONS = (
    "opencv-python-headless",
    "opencv-python",
    "opencv-contrib-python-headless",
    "opencv-contrib-python",
)


@functools.cache
def code_sha256() -> str:
    """SHA-256 of the toolkit's source (:data:`PACKAGES`): each ``.py`` file's path inside
    its package and bytes, in a fixed order; the same code in two folders gives the same
    digest."""
    digest = hashlib.sha256()
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        roots = list(dict.fromkeys(spec.submodule_search_locations or [])) if spec else []
        for root in map(Path, roots):
            for path in sorted(root.rglob("*.py")):
                data = path.read_bytes()
                digest.update(f"{name}/{path.relative_to(root).as_posix()}\0{len(data)}\0".encode())
                digest.update(data)
    return digest.hexdigest()


def _distribution_version(*names: str) -> str | None:
    for name in names:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return None


@functools.cache
def _versions() -> tuple[tuple[str, str | None], ...]:
    from graphslam import __version__

    return (
        ("graphslam", __version__),  # the code's own, not an installed copy's metadata
        ("gtsam", _distribution_version("gtsam")),
        ("numpy", _distribution_version("numpy")),
        ("opencv", _distribution_version(*OPENCV_DISTRIBUTIONS)),
        ("python", platform.python_version()),
    )


def versions() -> dict[str, str | None]:
    """Versions of graphslam, gtsam, numpy, OpenCV and Python (None: not installed)."""
    return dict(_versions())


def code_identity() -> dict:
    """What a result depends on besides its data and settings: :func:`versions` and
    :func:`code_sha256` (recorded in a run's provenance; a sweep compares them)."""
    return {"versions": versions(), "code_sha256": code_sha256()}


def invoked_as() -> list[str]:
    """How this process was started, as the first words of its command line:
    ``["python3", "-m", "graphslam"]`` (or ``graphslam.cli.main``, as a sweep starts its
    runs) when run as a module, else ``["graphslam"]`` (the console script, or
    :func:`graphslam.cli.main.main` called from Python)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", None) or ""
    if name.split(".", 1)[0] == "graphslam":
        return [Path(sys.executable).name or "python", "-m", name.removesuffix(".__main__")]
    return ["graphslam"]
