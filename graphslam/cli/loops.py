"""``graphslam loops IMAGES_DIR --out loops.csv``: place recognition on a folder of images.

Images in natural file-name order; vocabulary from ``--vocab`` or trained on
the fly on the folder itself; :class:`loopclosure.detector.LoopDetector`
settings from ``[loops]`` and ``[loop_verify]`` of ``--config``. Writes one CSV
row per accepted closure, ``query,match,score,inliers`` (file names, the
later image first), and optionally every candidate's fate as JSON lines.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

from slamcore.errors import InputError

EPILOG = """\
output:
  CSV with header query,match,score,inliers: one row per accepted closure,
  query = the later image, match = the earlier one (file names), score = DBoW2
  L1 similarity in [0, 1], inliers = RANSAC inliers of the geometric check.

detector (config sections, see loopclosure/detector.py and verify.py):
  [loops]        exclude_recent, min_normalised_score, consistency_k, ORB settings ...
  [loop_verify]  model, ratio, ransac_threshold_px, min_inliers, min_feature_share ...

examples:
  graphslam loops ../shared/data/kitti07/image_0 --out loops.csv
  graphslam loops frames/ --out loops.csv --vocab kitti.voc --log candidates.jsonl
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "loops", help="detect loop closures in a folder of images (bag of words + RANSAC)",
        description="Place recognition on a folder of images in file-name order: ORB features, "
                    "bag-of-words query, temporal consistency and geometric verification. "
                    "Writes one CSV row per accepted closure.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images_dir", type=Path, metavar="IMAGES_DIR",
                   help="folder of images (.png .jpg .jpeg .bmp .tif .tiff .pgm), taken in "
                        "natural file-name order as a time sequence")
    p.add_argument("--out", type=Path, required=True, metavar="FILE",
                   help="CSV file to write: query,match,score,inliers")
    p.add_argument("--vocab", type=Path, default=None, metavar="FILE",
                   help="vocabulary file from 'graphslam vocab train' (default: train one on "
                        "the folder itself, see --words)")
    p.add_argument("--words", type=int, default=1000, metavar="N",
                   help="words of the vocabulary trained on the fly when --vocab is not given "
                        "(default: 1000, a 10-way tree of depth 3)")
    p.add_argument("--intrinsics", type=Path, default=None, metavar="FILE",
                   help="camera intrinsics file (fx fy cx cy, or K; see graphslam.sources.spatial.images); "
                        "enables the essential-matrix check (default: fundamental matrix)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="TOML or YAML file with [loops] and [loop_verify] sections")
    p.add_argument("--log", type=Path, default=None, metavar="FILE",
                   help="write every candidate's fate (scores, inliers, accepted or why "
                        "rejected) as JSON lines")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_loops)


def check_vocabulary(vocab, path: Path) -> None:
    """Refuse (InputError naming ``path``) a vocabulary that cannot quantise ORB descriptors."""
    # ORB descriptors are 32-byte binary strings; a float vocabulary cannot quantise them.
    if getattr(vocab, "metric_", None) != "hamming" or getattr(vocab, "descriptor_dim_", None) != 32:
        raise InputError(f"vocabulary is not for ORB descriptors (metric "
                         f"{getattr(vocab, 'metric_', '?')}, dimension "
                         f"{getattr(vocab, 'descriptor_dim_', '?')}; need hamming, 32)", path)


def cmd_loops(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from graphslam.cli.vocab import describe, detect_all, folder_images, train_vocabulary
    from slamcore.config import load_section
    from frontend.image import load_gray
    from loopclosure.detector import LoopDetector, LoopDetectorConfig
    from loopclosure.verify import VerifyConfig
    from loopclosure.vocabulary import load_vocabulary

    t0 = time.perf_counter()
    paths = folder_images(args.images_dir)
    config = load_section(LoopDetectorConfig, args.config)
    verify_config = load_section(VerifyConfig, args.config)
    K = distortion = None
    if args.intrinsics is not None:
        from graphslam.sources.spatial.calibration import read_intrinsics_file

        K, distortion = read_intrinsics_file(args.intrinsics)

    features = None
    if args.vocab is not None:
        vocab = load_vocabulary(args.vocab)
        check_vocabulary(vocab, args.vocab)
    else:
        # One ORB pass serves both the training and the detection.
        from graphslam.cli.vocab import orb_for

        features = detect_all(paths, orb_for(args.config), quiet=args.quiet)
        print(f"training a vocabulary on {len(paths)} images ...", file=sys.stderr, flush=True)
        vocab = train_vocabulary([f.descriptors for f in features], args.words)
        print(f"vocabulary: {describe(vocab)}", file=sys.stderr)

    detector = LoopDetector(vocab, config, verify_config, K=K, distortion=distortion)
    bar = tqdm(range(len(paths)), desc="loops", unit="img", disable=args.quiet, file=sys.stderr)
    for i in bar:
        if features is None:
            detector.process(load_gray(paths[i]))
        else:
            f = features[i]
            features[i] = None  # free memory as we go
            detector.process_features(f.xy_px, f.descriptors)
        bar.set_postfix(closures=len(detector.closures), refresh=False)
    bar.close()

    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "match", "score", "inliers"])
        for c in detector.closures:
            w.writerow([paths[c.query].name, paths[c.match].name, f"{c.score:.6f}", c.n_inliers])
    written = [str(args.out)]
    if args.log is not None:
        args.log.parent.mkdir(parents=True, exist_ok=True)
        with args.log.open("w", encoding="utf-8") as fh:
            for r in detector.records:
                d = r.to_dict()
                d["query_name"] = paths[r.query].name
                d["match_name"] = None if r.match is None else paths[r.match].name
                fh.write(json.dumps(d) + "\n")
        written.append(str(args.log))
    print(f"{len(paths)} images, {len(detector.records)} candidates, "
          f"{len(detector.closures)} closures accepted, {time.perf_counter() - t0:.1f} s; "
          f"wrote {', '.join(written)}")
    return 0
