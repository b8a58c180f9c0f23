"""``graphslam vocab train IMAGES... --words N --out FILE``: train a visual vocabulary.

ORB features (the loop detector's settings, ``[loops]`` of ``--config``) on
every image, then a vocabulary tree with ``branching ** depth >= N`` leaves
(depth chosen as the smallest that reaches N) or, with ``--flat``, one k-means
of N words. Also holds the image listing and descriptor helpers shared with
``graphslam loops``.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import numpy as np

from slamcore.errors import ConfigError, InputError

#: Image file extensions read from folders (compared lower-case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")

EPILOG = """\
examples:
  graphslam vocab train ../shared/data/kitti07/image_0 --words 1000 --out kitti.voc
  graphslam vocab train a.png b.png c.png --words 500 --flat --out small.voc
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "vocab", help="visual vocabularies for loop closure (train)",
        description="Visual vocabularies (bag of words) for loop-closure detection.")
    sub = p.add_subparsers(dest="vocab_command", metavar="ACTION")
    sub.required = True
    t = sub.add_parser(
        "train", help="train a vocabulary from images",
        description="Detect ORB features on every image (progress bar), train a vocabulary tree "
                    "(hierarchical k-means, branching^depth >= --words leaves) or a flat "
                    "k-means vocabulary, and save it as one file.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    t.add_argument("images", nargs="+", metavar="IMAGES",
                   help="image files and/or folders (a folder contributes its images, "
                        "in file-name order, not recursively)")
    t.add_argument("--words", type=int, default=1000, metavar="N",
                   help="number of visual words wanted (default: 1000); a tree gets the "
                        "smallest depth with branching^depth >= N")
    t.add_argument("--out", type=Path, required=True, metavar="FILE",
                   help="vocabulary file to write (.npz archive, written under exactly this name)")
    t.add_argument("--flat", action="store_true",
                   help="one flat k-means of N words instead of a tree (slower to query)")
    t.add_argument("--branching", type=int, default=10, metavar="K",
                   help="branching factor of the tree (default: 10)")
    t.add_argument("--per-image", type=int, default=300, metavar="M",
                   help="train on the M strongest descriptors of each image (default: 300; "
                        "0 = all); bounds training time")
    t.add_argument("--seed", type=int, default=0, help="k-means seed (default: 0)")
    t.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="TOML or YAML file; ORB settings are read from its [loops] section")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_train)


# ----------------------------------------------------------------------------- shared helpers


def _natural_key(name: str):
    """``img2`` before ``img10``."""
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", name)]


def folder_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` in natural file-name order; InputError when none."""
    if not folder.is_dir():
        raise InputError("image folder not found", folder)
    paths = sorted((p for p in folder.iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                   key=lambda p: _natural_key(p.name))
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder", folder)
    return paths


def list_images(items: list[str | Path]) -> list[Path]:
    """Expand files and folders into image paths (folders in natural order)."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            out.extend(folder_images(p))
        elif p.is_file():
            out.append(p)
        else:
            raise InputError("no such image file or folder", p)
    return out


def detect_all(paths: list[Path], orb, quiet: bool = False, desc: str = "ORB") -> list:
    """ORB :class:`frontend.features.Features` of every image, with a progress bar."""
    from tqdm import tqdm

    from frontend.image import load_gray

    return [orb.detect(load_gray(p)) for p in tqdm(paths, desc=desc, unit="img", disable=quiet,
                                                    file=sys.stderr)]


def tree_depth(n_words: int, branching: int) -> int:
    """Smallest depth L with ``branching ** L >= n_words``."""
    depth = max(1, math.ceil(math.log(n_words) / math.log(branching) - 1e-9))
    while branching ** depth < n_words:
        depth += 1
    return depth


def train_vocabulary(descriptors: list[np.ndarray], n_words: int, flat: bool = False,
                     branching: int = 10, per_image: int = 300, seed: int = 0):
    """Fit a vocabulary on per-image (N, 32) uint8 descriptor arrays.

    Keeps the first ``per_image`` rows of each array (ORB output is sorted by
    decreasing response when the cell selection is off); 0 keeps all.
    """
    from loopclosure.vocabulary import FlatVocabulary, VocabularyTree

    if n_words < 2:
        raise ConfigError(f"--words must be at least 2, got {n_words}")
    if branching < 2:
        raise ConfigError(f"--branching must be at least 2, got {branching}")
    if per_image < 0:
        raise ConfigError(f"--per-image must be >= 0, got {per_image}")
    train = [d[:per_image] if per_image else d for d in descriptors]
    train = [d for d in train if len(d)]
    total = sum(len(d) for d in train)
    if total == 0:
        raise InputError("no ORB features found in the images: cannot train a vocabulary")
    if flat:
        if total < n_words:
            raise InputError(f"only {total} descriptors for {n_words} words: use fewer --words "
                             f"or more images")
        return FlatVocabulary(n_words=n_words, seed=seed).fit(train)
    return VocabularyTree(branching=branching, depth=tree_depth(n_words, branching),
                          seed=seed).fit(train)


def orb_for(config_path: Path | None):
    """The loop detector's ORB detector, from ``[loops]`` of the config file."""
    from slamcore.config import load_section
    from loopclosure.detector import LoopDetectorConfig
    from frontend.orb import OrbDetector

    c = load_section(LoopDetectorConfig, config_path)
    return OrbDetector(n_features=c.orb_n_features, cell_size_px=c.orb_cell_size_px,
                       per_cell=c.orb_per_cell, fast_threshold=c.orb_fast_threshold)


def describe(vocab) -> str:
    kind = type(vocab).__name__
    if kind == "VocabularyTree":
        return f"vocabulary tree k={vocab.branching} L={vocab.depth}, {vocab.n_words_} words"
    return f"flat vocabulary, {vocab.n_words_} words"


# ----------------------------------------------------------------------------- command


def cmd_train(args: argparse.Namespace) -> int:
    import time

    paths = list_images(args.images)
    orb = orb_for(args.config)
    feats = detect_all(paths, orb, quiet=args.quiet)
    t0 = time.perf_counter()
    print(f"training on {len(paths)} images ...", file=sys.stderr, flush=True)
    vocab = train_vocabulary([f.descriptors for f in feats], args.words, flat=args.flat,
                             branching=args.branching, per_image=args.per_image, seed=args.seed)
    wall = time.perf_counter() - t0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    vocab.save(args.out)
    n_desc = sum(min(len(f), args.per_image) if args.per_image else len(f) for f in feats)
    print(f"wrote {args.out}: {describe(vocab)}, from {n_desc} descriptors of {len(paths)} "
          f"images, trained in {wall:.1f} s")
    return 0
