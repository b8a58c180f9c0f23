"""Train the general ORB vocabulary shipped with the package (loopclosure/data/orb_vocabulary.npz).

A folder of ten images must not be quantised by a vocabulary trained on those
ten: `graphslam loops` loads this one by default. It is trained on varied
real images this project can read without downloading anything, and rendered
textures:

- KITTI 07 frames 0-159, every 2nd (outdoor driving, 1226x370 greyscale);
- the 12 Lund door photos (a building facade, 1296x1936);
- the 10 slambook2 desk photos (indoor office, 640x480);
- the 5 Balbianello photos of the gtsam wheel (a lakeside villa);
- every 3rd frame of the default rendered synthetic sequence (textured room);
- scikit-image's sample images when scikit-image is installed (not here when
  this file was trained: see datasets/README.md).

ORB is the loop detector's own (``LoopDetectorConfig().orb``, 1000
features); large images are first halved until their long side is at most
1280 px, so a photo does not outweigh a video frame by its pixel count alone.
Tree: k = 10, L = 4 (10 000 words, DBoW2's default shape is k = 10, L = 6 on
millions of descriptors; 10^4 words keeps the file near 1 MB), seed 0.

    python benchmarks/train_shipped_vocabulary.py [--out loopclosure/data/orb_vocabulary.npz]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from frontend.image import load_gray
from frontend.orb import OrbDetector
from loopclosure.detector import LoopDetectorConfig
from loopclosure.vocabulary import VocabularyTree
import entry  # noqa: E402  (beside this script: its argparse types)

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data"
#: Long side (px) above which an image is halved before ORB.
MAX_SIDE_PX = 1280


def _shrink(img: np.ndarray) -> np.ndarray:
    while max(img.shape) > MAX_SIDE_PX:
        img = cv2.pyrDown(img)
    return img


def training_images() -> dict[str, list]:
    """Source name -> list of greyscale images (loaded lazily as paths or arrays)."""
    out: dict[str, list] = {
        "kitti07": sorted((DATA / "kitti07" / "image_0").glob("*.png"))[::2],
        "lund_door": sorted((DATA / "lund_door" / "images").glob("*.JPG")),
        "slambook2_desk": sorted((DATA / "slambook2_desk" / "images").glob("*.png")),
    }
    try:
        import gtsam

        out["gtsam Balbianello"] = sorted(Path(gtsam.findExampleDataFile("Balbianello")).glob("*.jpg"))
    except (ImportError, RuntimeError):
        out["gtsam Balbianello"] = []
    from graphslam.sources.spatial.synthetic_images import make_synthetic_images

    seq = make_synthetic_images()
    out["synthetic"] = [seq.load(i) for i in range(0, len(seq.image_paths), 3)]
    try:
        import skimage.data as sk

        out["scikit-image"] = [sk.camera(), sk.astronaut()[..., 0], sk.coffee()[..., 0],
                               sk.chelsea()[..., 0], sk.brick(), sk.grass(), sk.gravel()]
    except ImportError:
        out["scikit-image"] = []
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=entry.output_file, default=HERE.parent / "loopclosure" / "data" / "orb_vocabulary.npz")
    args = ap.parse_args(argv)
    orb = OrbDetector(LoopDetectorConfig().orb)
    descriptors = []
    for name, items in training_images().items():
        n = 0
        for item in items:
            img = load_gray(item) if isinstance(item, Path) else item
            d = orb.detect(_shrink(img)).descriptors
            if len(d):
                descriptors.append(d)
                n += len(d)
        print(f"{name}: {len(items)} images, {n} descriptors", file=sys.stderr)
    t0 = time.perf_counter()
    vocab = VocabularyTree(branching=10, depth=4, seed=0).fit(descriptors)
    print(f"trained {vocab.n_words_} words on {sum(len(d) for d in descriptors)} descriptors "
          f"from {len(descriptors)} images in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    vocab.save(args.out)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
