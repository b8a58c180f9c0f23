"""The general ORB vocabulary shipped with the package (``loopclosure/data/orb_vocabulary.npz``).

A 10-way tree of depth 4 (about 10 000 words) trained by
``benchmarks/train_shipped_vocabulary.py`` on varied real images (KITTI 07,
the Lund door, the slambook2 desk, gtsam's Balbianello photos) and rendered
textures; provenance, size and load time in ``datasets/README.md``. It is
what ``graphslam loops`` quantises with when no ``--vocab`` is given, so a
small folder is not described by words learnt from itself alone.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["SHIPPED_VOCABULARY", "load_shipped_vocabulary"]

#: Path of the shipped vocabulary file (package data).
SHIPPED_VOCABULARY = Path(__file__).resolve().parent / "data" / "orb_vocabulary.npz"


def load_shipped_vocabulary():
    """The shipped :class:`loopclosure.vocabulary.VocabularyTree` (InputError if the file is missing)."""
    from loopclosure.vocabulary import load_vocabulary

    return load_vocabulary(SHIPPED_VOCABULARY)
