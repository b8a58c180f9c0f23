"""``graphslam vocab train IMAGES... --words N --out FILE``: train a visual vocabulary.

ORB features (the loop detector's settings, ``[loops.orb]`` of ``--config``) on
every image, then a vocabulary tree with ``branching ** depth >= N`` leaves
(depth chosen as the smallest that reaches N) or, with ``--flat``, one k-means
of N words.
"""

from __future__ import annotations

import argparse
import os
import sys

from graphslam.cli.common import (
    add_command,
    add_config_option,
    add_quiet_option,
    file_out_arg,
    kmeans_seed_arg,
)

EPILOG = """\
examples:
  graphslam vocab train ../shared/data/kitti07/image_0 --words 1000 --out kitti.voc
  graphslam vocab train a.png b.png c.png --words 500 --flat --out small.voc
"""


def register(subparsers) -> None:
    p = add_command(
        subparsers,
        "vocab",
        None,
        help="visual vocabularies for loop closure (train)",
        description="Visual vocabularies (bag of words) for loop-closure detection.",
    )
    sub = p.add_subparsers(dest="vocab_command", metavar="ACTION")
    sub.required = True
    t = add_command(
        sub,
        "train",
        cmd_train,
        help="train a vocabulary from images",
        description="Detect ORB features on every image (progress bar), train a vocabulary tree "
        "(hierarchical k-means, branching^depth >= --words leaves) or a flat "
        "k-means vocabulary, and save it as one file.",
        epilog=EPILOG,
    )
    t.add_argument(
        "images",
        nargs="+",
        metavar="IMAGES",
        help="image files and/or folders (a folder contributes its images, "
        "in file-name order, not recursively)",
    )
    t.add_argument(
        "--words",
        type=int,
        default=1000,
        metavar="N",
        help="number of visual words wanted (default: 1000); a tree gets the "
        "smallest depth with branching^depth >= N",
    )
    t.add_argument(
        "--out",
        type=file_out_arg,
        required=True,
        metavar="FILE",
        help="vocabulary file to write (.npz archive, written under exactly this name)",
    )
    t.add_argument(
        "--flat", action="store_true", help="one flat k-means of N words instead of a tree (slower to query)"
    )
    t.add_argument(
        "--branching",
        type=int,
        default=None,
        metavar="K",
        help="branching factor of the tree, 2 to 1000 (default: 10; refused with --flat, which builds none)",
    )
    t.add_argument(
        "--per-image",
        type=int,
        default=300,
        metavar="M",
        help="train on the M strongest descriptors of each image (default: 300; "
        "0 = all); bounds training time",
    )
    t.add_argument(
        "--seed", type=kmeans_seed_arg, default=0, help="k-means seed, 0 to 2**32 - 1 (default: 0)"
    )
    add_config_option(
        t, "TOML or YAML file; ORB settings are read from its [loops.orb] table", metavar="FILE"
    )
    add_quiet_option(t)


# ----------------------------------------------------------------------------- command


#: descriptors x words of a flat k-means above which its time is minutes: measured on
#: KITTI 07's 160k ORB descriptors, 1000 words (1.6e8) 11 s and 4000 (6.4e8) 107 s here
FLAT_SLOW_PRODUCT = 5e8


def cmd_train(args: argparse.Namespace) -> int:
    import time

    from frontend.orb import OrbDetector
    from graphslam.cli.common import EXIT_INTERRUPTED, warn, warn_unread_sections
    from graphslam.pipelines.common import active_guard, stop_requested
    from graphslam.pipelines.place_recognition import (
        check_training_settings,
        describe,
        detect_all,
        train_vocabulary,
        vocabulary_doubt,
    )
    from graphslam.registry import read_config
    from graphslam.sources.spatial.sequence import expand_images, natural_key
    from loopclosure.detector import LoopDetectorConfig
    from slamcore.files import check_not_inputs, check_output_file, replacing

    check_output_file(args.out)  # refused now, not after the training
    if args.flat and args.branching is not None:
        from slamcore.errors import ConfigError

        raise ConfigError("--branching is the tree's; --flat trains one flat k-means, no tree")
    from graphslam.registry import is_bag_dataset
    from slamcore.errors import InputError

    for item in args.images:  # read as one image file it "could not be read": say what it is
        if is_bag_dataset(str(item)):
            raise InputError(
                "is a ROS bag: vocab train reads image files and folders (graphslam loops BAG "
                "--words N trains a vocabulary on a bag's images for its own search)",
                item,
            )
    paths, repeats = expand_images(args.images)
    # k-means starts from the descriptors' order: the same images listed in another
    # order (a shell's glob under another locale) must give the same vocabulary
    # (natural order of the real paths: a folder trains as loops --words trains on it)
    paths = sorted(paths, key=lambda p: natural_key(os.path.realpath(p)))
    if repeats:  # a repeat would count twice in the k-means and in the IDF
        warn(
            f"{repeats} image(s) given more than once (a file and its folder, or a file "
            "twice): each trained on once"
        )
    check_not_inputs(  # an image written over (--out IMAGES/01.png)
        [("--out", args.out)], {"--config": args.config, **{f"image {p}": p for p in paths}}
    )
    tree = {} if args.branching is None else {"branching": args.branching}  # else the library's
    check_training_settings(args.words, per_image=args.per_image, **tree)  # before the ORB pass
    config = read_config(args.config)
    orb = OrbDetector(config.section(LoopDetectorConfig).orb)
    loops_keys = [k for k in config.data.get("loops") or {} if k != "orb"]
    config.mark_inert("loops", loops_keys, "loops and run --loops (vocab train reads [loops.orb] only)")
    warn_unread_sections(config, args.config, "vocab train (it reads the loop detector's [loops.orb])")
    # A stop during the ORB pass trains on the images described so far; one
    # during the training lets it finish (a second one aborts, the old file kept).
    feats = detect_all(paths, orb, progress=not args.quiet, stoppable=True)
    if stop_requested() and not feats:
        raise KeyboardInterrupt
    t0 = time.perf_counter()
    # said now: a first stop is held until the k-means ends (tens of seconds on 160 KITTI
    # frames), and nothing can be said while it runs
    print(
        f"training on {len(feats)} images ... (Ctrl-C lets the training finish and writes it; "
        "a second Ctrl-C aborts, any old file kept)",
        file=sys.stderr,
        flush=True,
    )
    n_desc = sum(min(len(f), args.per_image) if args.per_image else len(f) for f in feats)
    # (a flat k-means of more words than descriptors is refused below: no warning first)
    if args.flat and n_desc >= args.words and n_desc * args.words > FLAT_SLOW_PRODUCT:
        warn(
            f"a flat k-means of {args.words} words on {n_desc} descriptors computes "
            f"{n_desc * args.words:.1e} distances an iteration: minutes, with no progress to show; "
            "the tree (without --flat) trains this size in seconds"
        )
    guard = active_guard()
    if guard is not None:
        guard.held_note = "stop asked: the training ends first and is written (Ctrl-C again aborts it)"
    vocab = train_vocabulary(
        [f.descriptors for f in feats],
        args.words,
        flat=args.flat,
        **tree,
        per_image=args.per_image,
        seed=args.seed,
    )
    wall = time.perf_counter() - t0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with replacing(args.out) as tmp:
        vocab.save(tmp)
    print(
        f"wrote {args.out}: {describe(vocab)}, from {n_desc} descriptors of {len(feats)} "
        f"images, trained in {wall:.1f} s"
    )
    if (doubt := vocabulary_doubt(vocab)) is not None:
        warn(doubt)
    if n_desc < args.words:  # a flat k-means refuses this; a tree stops where nodes run dry
        warn(
            f"--words {args.words}: only {n_desc} descriptors, the tree has {vocab.n_words_} "
            "words; more images, or a larger --per-image, give it more"
        )
    guard = active_guard()
    if guard is not None and guard.requested:  # stop_requested(), the guard narrowed
        print(
            f"graphslam: interrupted ({guard.signal_name}); the vocabulary is "
            f"trained on {len(feats)} of {len(paths)} images",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    return 0
