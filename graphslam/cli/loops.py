"""``graphslam loops IMAGES_DIR --out loops.csv``: place recognition on a folder of images.

Images in natural file-name order; vocabulary from ``--vocab`` or trained on
the fly on the folder itself; :class:`loopclosure.detector.LoopDetector`
settings from ``[loops]`` and ``[loop_verify]`` of ``--config``. Writes one CSV
row per accepted closure, ``query,match,score,inliers`` (file names, the
later image first), and optionally every candidate's fate as JSON lines.
"""

from __future__ import annotations

import argparse
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
  [loops]        exclude_recent, min_normalised_score, consistency_k ...
  [loops.orb]    the detector's ORB: n_features, cell_size_px, fast_threshold ...
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
    p.add_argument("--frames", default=None, metavar="START:STOP[:STEP]",
                   help="use these images only (Python slice of the file-name order)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_loops)


def cmd_loops(args: argparse.Namespace) -> int:
    from frontend.orb import OrbDetector
    from graphslam.pipelines.place_recognition import (
        check_vocabulary, describe, detect_all, detect_loops, train_vocabulary,
    )
    from graphslam.sources.spatial.sequence import folder_images
    from graphslam.registry import read_config
    from loopclosure.detector import LoopDetector, LoopDetectorConfig
    from loopclosure.verify import VerifyConfig
    from loopclosure.vocabulary import load_vocabulary

    t0 = time.perf_counter()
    paths = folder_images(args.images_dir)
    if args.frames is not None:
        from graphslam.sources.spatial.frames import frame_indices, parse_frames

        paths = [paths[i] for i in frame_indices(parse_frames(args.frames), len(paths))]
    config = read_config(args.config)
    detector_config = config.section(LoopDetectorConfig)
    verify_config = config.section(VerifyConfig)
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
        features = detect_all(paths, OrbDetector(detector_config.orb), progress=not args.quiet)
        print(f"training a vocabulary on {len(paths)} images ...", file=sys.stderr, flush=True)
        vocab = train_vocabulary([f.descriptors for f in features], args.words)
        print(f"vocabulary: {describe(vocab)}", file=sys.stderr)

    detector = LoopDetector(vocab, detector_config, verify_config, K=K, distortion=distortion)
    detect_loops(paths, detector, features, progress=not args.quiet)

    from graphslam.outputs.loops import write_candidates_jsonl, write_folder_loops_csv

    write_folder_loops_csv(args.out, detector.closures, paths)
    written = [str(args.out)]
    if args.log is not None:
        write_candidates_jsonl(args.log, detector.records, paths)
        written.append(str(args.log))
    print(f"{len(paths)} images, {len(detector.records)} candidates, "
          f"{len(detector.closures)} closures accepted, {time.perf_counter() - t0:.1f} s; "
          f"wrote {', '.join(written)}")
    return 0
