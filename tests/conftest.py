"""Shared test fixtures: paths to the shared real data."""

from __future__ import annotations

import os
from pathlib import Path

# One thread per test process: the suite runs on two processes (-n 2), and BLAS and
# OpenCV threads on top of them oversubscribed two cores (measured on the visual and
# front-end tests: 171 -> 156 s wall, 236 -> 184 s CPU). Set before numpy or cv2 is
# imported; the command lines the tests start inherit it; a setting of the user's wins.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_var, "1")

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA
