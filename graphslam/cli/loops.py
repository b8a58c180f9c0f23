"""``graphslam loops IMAGES_DIR --out loops.csv``: place recognition on a folder of images.

Images in natural file-name order; vocabulary from ``--vocab``, trained on
the fly on the folder itself with ``--words N``, else the general one shipped
with the package (:mod:`loopclosure.shipped`); :class:`loopclosure.detector.LoopDetector`
settings from ``[loops]`` and ``[loop_verify]`` of ``--config``. Writes one CSV
row per accepted closure, ``query,match,score,inliers`` (file names, the
later image first), and optionally every candidate's fate as JSON lines.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from graphslam.cli.common import (
    add_command,
    add_config_option,
    add_frames_option,
    add_quiet_option,
    add_topics_option,
    file_out_arg,
    path_arg,
    warn,
)
from graphslam.cli.out_folder import claim_out_dir, clear_earlier_outputs
from slamcore.errors import ConfigError
from slamcore.files import check_distinct_outputs, check_not_inputs, check_output_file

EPILOG = """\
output:
  CSV with header query,match,score,inliers: one row per accepted closure,
  query = the later image, match = the earlier one (file names), score = DBoW2
  L1 similarity in [0, 1], inliers = RANSAC inliers of the geometric check.

detector (config sections, see loopclosure/detector.py and verify.py):
  [loops]        mode (covisibility, the default; video, keyframes, auto),
                 min_shared_tracks, min_normalised_score, consistency_k ...;
                 exclude_recent(_s) with mode = "video" or "auto"
  [loops.orb]    the detector's ORB: n_features, cell_size_px, fast_threshold ...
  [loop_verify]  model, ratio, ransac_threshold_px, min_inliers, min_feature_share ...

examples:
  graphslam loops ../shared/data/kitti07/image_0 --out loops.csv
  graphslam loops frames/ --out loops.csv --vocab kitti.voc --log candidates.jsonl
"""


def register(subparsers) -> None:
    p = add_command(
        subparsers,
        "loops",
        cmd_loops,
        help="detect loop closures in a folder of images (bag of words + RANSAC)",
        description="Place recognition on a folder of images in file-name order: ORB features, "
        "bag-of-words query, temporal consistency and geometric verification. "
        "Writes one CSV row per accepted closure.",
        epilog=EPILOG,
    )
    p.add_argument(
        "images_dir",
        type=path_arg,
        metavar="IMAGES_DIR",
        help="folder of images (.png .jpg .jpeg .bmp .tif .tiff .pgm), taken in "
        "natural file-name order as a time sequence, or a ROS bag (its image "
        "topic in header-stamp order; its camera info as --intrinsics)",
    )
    add_topics_option(p)
    p.add_argument(
        "--out",
        type=file_out_arg,
        required=True,
        metavar="FILE",
        help="CSV file to write: query,match,score,inliers",
    )
    p.add_argument(
        "--vocab",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="vocabulary file from 'graphslam vocab train' (default: the general "
        "9 991-word ORB vocabulary shipped with the package)",
    )
    p.add_argument(
        "--words",
        type=int,
        default=None,
        metavar="N",
        help="instead, train a vocabulary of N words on the folder itself "
        "(e.g. 1000, a 10-way tree of depth 3)",
    )
    p.add_argument(
        "--intrinsics",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="camera intrinsics file (fx fy cx cy, or K; see graphslam.sources.spatial.images); "
        "enables the essential-matrix check (default: fundamental matrix)",
    )
    add_config_option(p, "TOML or YAML file with [loops] and [loop_verify] sections", metavar="FILE")
    p.add_argument(
        "--log",
        type=file_out_arg,
        default=None,
        metavar="FILE",
        help="write every candidate's fate (scores, inliers, accepted or why rejected) as JSON lines",
    )
    p.add_argument(
        "--truth",
        type=path_arg,
        default=None,
        metavar="FILE",
        help="true same-place pairs: a CSV 'query,match' of file names, or an N x N "
        "image whose non-zero pixel (i, j) marks images i and j as one place; "
        "prints precision and recall and writes pr.csv and pr.png next to --out",
    )
    add_frames_option(p, "use these images only (Python slice of the file-name order)")
    add_quiet_option(p)


def cmd_loops(args: argparse.Namespace) -> int:
    from frontend.orb import OrbDetector
    from graphslam.cli.common import EXIT_INTERRUPTED
    from graphslam.pipelines.common import active_guard, stop_requested
    from graphslam.pipelines.place_recognition import (
        check_training_settings,
        check_vocabulary,
        describe,
        detect_all,
        detect_loops,
        featureless_images,
        folder_places,
        train_vocabulary,
        vocabulary_doubt,
    )
    from graphslam.registry import read_config
    from loopclosure.detector import LoopDetector, LoopDetectorConfig
    from loopclosure.shipped import SHIPPED_VOCABULARY
    from loopclosure.verify import VerifyConfig
    from loopclosure.vocabulary import load_vocabulary

    t0 = time.perf_counter()
    check_output_file(args.out)  # refused now, not after the detection
    if args.log is not None:
        check_output_file(args.log, "--log")
    pr_files = {}
    if args.truth is not None:  # pr.csv and pr.png beside --out: --out pr.csv would be lost
        beside = "(written beside --out with --truth)"
        pr_files = {f"{name} {beside}": args.out.parent / name for name in ("pr.csv", "pr.png")}
    check_distinct_outputs({"--out": args.out, "--log": args.log, **pr_files})
    from graphslam.sources.spatial.sequence import folder_images

    paths, times, truth, bag = _images(args)
    check_not_inputs(  # an image or the bag written over (--out IMAGES/01.png)
        [("--out", args.out), ("--log", args.log), *pr_files.items()],
        {
            "IMAGES_DIR": args.images_dir,
            **{"--" + flag: getattr(args, flag, None) for flag in ("truth", "vocab", "config", "intrinsics")},
            **{f"image {p}": p for p in (paths if bag is not None else folder_images(args.images_dir))},
        },
    )
    # pr.png in the image folder becomes a frame of the next run on that folder
    in_images = bag is None and args.out.parent.resolve() == Path(args.images_dir).resolve()
    if args.truth is not None and in_images:
        raise ConfigError(
            f"--truth writes pr.csv and pr.png beside --out, here in IMAGES_DIR {args.images_dir} "
            "itself, where the next run on the folder would read pr.png as an image; choose --out "
            "in another folder"
        )
    config = read_config(args.config)
    detector_config = config.section(LoopDetectorConfig)
    verify_config = config.section(VerifyConfig)
    K, distortion = _camera(args, bag, paths)
    _check_camera_use(verify_config.model, K, config)

    if args.vocab is not None and args.words is not None:
        raise ConfigError("give --vocab FILE or --words N, not both")
    if args.words is not None:  # refused now, not after the ORB pass
        check_training_settings(args.words)
    vocab = None
    if args.words is None:  # a bad file fails before the long ORB pass
        vocab_path = SHIPPED_VOCABULARY if args.vocab is None else args.vocab
        vocab = load_vocabulary(vocab_path)
        check_vocabulary(vocab, vocab_path)
    # One ORB pass serves the mode choice, the training (if any) and the detection.
    features = detect_all(
        paths,
        OrbDetector(detector_config.orb),
        progress=not args.quiet,
        load=_bag_loader(bag) if bag is not None else (_one_camera_loader() if K is not None else None),
    )
    featureless = featureless_images(features, args.images_dir)  # all of them: refused
    places = folder_places(features, detector_config, times)
    if vocab is None:
        print(f"training a vocabulary on {len(paths)} images ...", file=sys.stderr, flush=True)
        vocab = train_vocabulary([f.descriptors for f in features], args.words)
        print(f"vocabulary: {describe(vocab)}", file=sys.stderr)
        if vocab.n_words_ < args.words:  # as vocab train says it: the tree stops where nodes run dry
            warn(
                f"--words {args.words}: the tree has {vocab.n_words_} words, too few descriptors "
                "for more; more images give it more"
            )
    if (doubt := vocabulary_doubt(vocab)) is not None:  # the shipped one's weights are not all 0
        warn(doubt)

    detector = LoopDetector(
        vocab,
        detector_config,
        verify_config,
        K=K,
        distortion=distortion,
        mode=places.mode if detector_config.mode == "auto" else None,
    )
    kept = list(features) if args.truth is not None else None  # detect_loops frees its list
    detect_loops(paths, detector, features, progress=not args.quiet, timestamps=places.timestamps)

    from graphslam.outputs.loops import write_candidates_jsonl, write_folder_loops_csv

    claim_out_dir(args.out.parent)
    evaluated = args.truth is not None and not stop_requested()  # a cut run has no whole PR curve
    if not evaluated and not in_images:  # an earlier --truth run's curve is not this run's
        clear_earlier_outputs(args.out.parent, set(), ("pr.csv", "pr.png"))
    write_folder_loops_csv(args.out, detector.closures, paths)
    written = [str(args.out)]
    if args.log is not None:
        write_candidates_jsonl(args.log, detector.records, paths)
        written.append(str(args.log))
    if evaluated:
        written += _evaluate(args, truth, paths, kept, detector, places.timestamps)
    from graphslam.cli.common import warn_unread_sections

    warn_unread_sections(config, args.config, "loops")
    guard = active_guard()
    seen = f"{len(detector)} of {len(paths)}" if stop_requested() else f"{len(paths)}"
    print(f"places: {places.describe(detector_config, detector.excluded)}")
    if featureless:
        print(
            f"{featureless} of {len(paths)} images gave no ORB feature (blank, flat or too small): "
            "they can close no loop"
        )
    # closures verified from a second view of the candidate's place ([loops] second_views)
    second = sum(r.accepted and r.second_view_of is not None for r in detector.records)
    n_records, n_closures = len(detector.records), len(detector.closures)
    print(
        f"{seen} image{'s' * (len(paths) != 1)}, {n_records} candidate{'s' * (n_records != 1)}, "
        f"{n_closures} closure{'s' * (n_closures != 1)} accepted"
        + (f" ({second} from a second view of the candidate's place)" if second else "")
        + f", {time.perf_counter() - t0:.1f} s; wrote {', '.join(written)}"
    )
    if guard is not None and guard.requested:  # stop_requested(), the guard narrowed
        print(
            f"graphslam: interrupted ({guard.signal_name}); wrote the closures found in the images seen",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    return 0


def _images(args):
    """``(paths, timestamps or None, truth pairs or None, the bag's sequence or None)``
    of the folder or bag and ``--frames``; a bad ``--truth`` is refused here, before
    the long ORB pass."""
    from graphslam.pipelines.place_recognition import folder_timestamps
    from graphslam.registry import check_topics_flag, is_bag_dataset
    from graphslam.sources.spatial.sequence import check_utf8_names, folder_images

    check_topics_flag(str(args.images_dir), args.topics)
    bag = None
    if is_bag_dataset(str(args.images_dir)):
        from graphslam.sources.spatial.rosbag import parse_topics, read_bag

        # ground truth poses are not read: the same-place pairs come from --truth
        bag = read_bag(
            args.images_dir,
            {"truth": "none", "odometry": "none", **parse_topics(args.topics)},
            calibrated=False,
        )
        paths = [Path(p) for p in bag.image_paths]  # <bag>#<topic>/000042: names 000042
        times = bag.stamps_s
    else:
        paths = folder_images(args.images_dir)
        check_utf8_names(paths, "the closures name images by file name (UTF-8 text)")
        times = folder_timestamps(paths)  # of the whole folder: a times.txt matches it only
    truth = None
    if args.truth is not None:  # of the whole folder: --frames may leave some of its images out
        from graphslam.evaluation.places import read_truth

        truth = read_truth(args.truth, paths)
    if args.frames is not None:
        from graphslam.evaluation.places import restrict_truth
        from graphslam.sources.spatial.frames import frame_indices, parse_frames

        index = frame_indices(parse_frames(args.frames), len(paths))
        paths = [paths[i] for i in index]
        times = None if times is None else times[index]
        if truth is not None:
            truth, outside = restrict_truth(truth, index)
            if outside:
                from graphslam.cli.common import warn

                warn(
                    f"{args.truth}: {outside} of its same-place pairs name an image --frames "
                    f"{args.frames} leaves out; scored on the other {len(truth)}"
                )
    return paths, times, truth, bag


def _check_camera_use(model: str, K, config) -> None:
    """Refuse ``[loop_verify] model = "essential"`` without a camera (it failed at the first
    pair, naming neither file nor line), and say that "fundamental" or "homography" leaves
    ``--intrinsics`` unused: the essential-matrix check the help promises with it is off,
    and the run was identical to one without it, unsaid (hostile pass 22)."""
    line = config.line_of("loop_verify", "model")
    if model == "essential" and K is None:
        raise ConfigError(
            '[loop_verify] model = "essential" needs the camera: give --intrinsics (or "auto")',
            config.path,
            line,
        )
    if K is not None and model in ("fundamental", "homography"):
        warn(
            f'--intrinsics: [loop_verify] model = "{model}" (--config line {line}) '
            "checks pairs without the camera; only its distortion, if any, is used"
        )


def _camera(args, bag, paths):
    """``(K, distortion)`` of ``--intrinsics`` (checked against the first image; its
    doubts said as warnings), else of the bag (a calibrated essential-matrix check),
    else ``(None, None)`` (the fundamental matrix)."""
    if args.intrinsics is not None and bag is None:
        from graphslam.cli.common import warn
        from graphslam.sources.spatial.calibration import read_camera_of

        K, dist, doubts = read_camera_of(args.intrinsics, paths[0])
        for doubt in doubts:
            warn(doubt)
        return K, dist
    if args.intrinsics is not None:
        from graphslam.sources.spatial.calibration import read_intrinsics_file

        return read_intrinsics_file(args.intrinsics)
    return (None, None) if bag is None else (bag.K, bag.distortion)


def _one_camera_loader():
    """``load(path)`` that refuses an image of another size than the first: ``--intrinsics``
    is one camera at one resolution, and a photo of another size matched under its K
    lost its true closure without a word (``run`` refuses it as well)."""
    from frontend.image import load_gray
    from slamcore.errors import InputError

    first: list = []

    def load(path):
        image = load_gray(path)
        if not first:
            first.append((Path(path).name, image.shape))
        elif image.shape != first[0][1]:
            (name, (h, w)) = first[0]
            raise InputError(
                f"image is {image.shape[1]}x{image.shape[0]} px, {name} is {w}x{h}: --intrinsics "
                "describes one camera at one resolution (without it, images of any size are matched)",
                path,
            )
        return image

    return load


def _bag_loader(bag):
    """``load(path)`` of a bag's pseudo-paths: the stored image, lens distortion kept
    (the detector is given the distortion, as with a folder and --intrinsics)."""
    index = {p: i for i, p in enumerate(Path(q) for q in bag.image_paths)}
    return lambda p: bag.load_raw(index[p])


def _evaluate(args, truth, paths, features, detector, timestamps) -> list[str]:
    """``--truth``: precision and recall printed, the PR curve written; returns the files."""
    from graphslam.evaluation.places import pr_curve, score
    from graphslam.pipelines.place_recognition import sweep_scores
    from loopclosure.detector import LoopDetector

    closures = [(c.query, c.match) for c in detector.closures]
    precision, recall, n_true = score(closures, truth)
    # The sweep: the same detector with no score threshold, every verified candidate kept.
    loose = dataclasses.replace(detector.config, min_normalised_score=0.0, min_score=0.0)
    sweep = LoopDetector(
        detector.database.vocabulary,
        loose,
        verifier=detector.verifier,
        K=detector.K,
        distortion=detector.distortion,
        mode=detector.mode if loose.mode == "auto" else None,
    )
    points = pr_curve(sweep_scores(paths, features, sweep, timestamps), truth)
    files = write_pr(points, (precision, recall), args.out.parent)
    n_queries = len({q for q, _ in truth})
    prec = "n/a (no closure)" if precision is None else f"{precision:.3f}"
    rec = "n/a (no true pair)" if recall is None else f"{recall:.3f}"
    print(
        f"truth: {len(truth)} same-place pairs, {n_queries} queries with a true match; "
        f"precision {prec} ({n_true}/{len(closures)}), recall {rec}"
    )
    return [str(f) for f in files]


def _csv_number(value: float | None) -> str:
    """A pr.csv field: six decimals, or ``n/a`` where the figure is undefined."""
    return "n/a" if value is None else f"{value:.6f}"


def write_pr(points, operating: tuple[float | None, float | None], out_dir: Path) -> list[Path]:
    """``pr.csv`` (threshold,closures,true,precision,recall; ``n/a`` where undefined) and
    ``pr.png`` in ``out_dir``. Without a true pair recall is undefined: the plot is
    written all the same (an empty frame, no stale curve of an earlier run left beside
    the new pr.csv), with no operating point."""
    from graphslam.visualisation.plots import plot_precision_recall

    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "pr.csv"
    with csv_path.open("w", encoding="utf-8") as fh:
        fh.write("threshold,closures,true,precision,recall\n")
        for p in points:
            fh.write(
                f"{p.threshold:.6f},{p.closures},{p.true},{_csv_number(p.precision)},{_csv_number(p.recall)}\n"
            )
    precision, recall = operating
    marked = (None, 0.0) if recall is None else (precision, recall)  # precision None: no marker
    return [csv_path, plot_precision_recall(points, marked, out_dir / "pr.png")]
