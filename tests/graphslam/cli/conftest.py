"""Fixtures of the CLI tests."""

from __future__ import annotations

import shutil

import pytest


@pytest.fixture
def desk_copy(shared_data, tmp_path):
    """``desk_copy(n)``: a folder ``photos`` of the first ``n`` slambook2 desk photos
    (``01.png`` ...), no camera file; skipped without the photos."""
    src = shared_data / "slambook2_desk" / "images"
    if not src.is_dir():
        pytest.skip("desk photos missing")

    def copy(n: int):
        folder = tmp_path / "photos"
        folder.mkdir()
        for k in range(1, n + 1):
            shutil.copy(src / f"{k:02d}.png", folder / f"{k:02d}.png")
        return folder

    return copy
