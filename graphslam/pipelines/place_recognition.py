"""Place recognition as the ``loops`` and ``vocab`` commands and the visual run use it:
ORB features of an image list, vocabulary training, and loop detection over a folder.

Library functions: they compute and return; the CLI prints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphslam.pipelines.common import interrupt_between_frames, signal_hook
from slamcore.errors import ConfigError, InputError


def detect_all(
    paths: list[Path], orb, progress: bool = False, desc: str = "ORB", stoppable: bool = False, load=None
) -> list:
    """ORB :class:`frontend.features.Features` of every image (progress bar on stderr).

    ``stoppable``: a stop request (SIGINT, SIGTERM; :mod:`graphslam.pipelines.common`)
    ends the pass at the next image and the features so far are returned
    (fewer than ``paths``); otherwise a signal aborts it. ``load(path)`` reads an
    image (default :func:`frontend.image.load_gray`).
    """
    from frontend.image import load_gray
    from graphslam.pipelines.progress import progress as progress_of

    read = load or load_gray  # ``load(path)``: images that are not files (a ROS bag's)
    bar = progress_of(paths, desc=desc, unit="img", enabled=progress)
    if not stoppable:
        return [orb.detect(read(p)) for p in bar]
    features = []
    with interrupt_between_frames() as stop:
        for i, p in enumerate(bar):
            if stop.requested:
                break
            features.append(orb.detect(read(p)))
            signal_hook("step", i)
    bar.close()
    return features


def featureless_images(features: list, where: str | Path) -> int:
    """How many of the images' ORB ``features`` hold none (a blank, flat or tiny image):
    such an image can neither find an older one nor be found. InputError naming
    ``where`` (the folder) when every image is featureless: no closure can be found,
    and a run that says "0 closures" would not say why."""
    n = sum(len(f) == 0 for f in features)
    if features and n == len(features):
        raise InputError(
            f"no ORB features found in the images ({n} of {n} blank, flat or too small): "
            "no closure can be found",
            where,
        )
    return n


def tree_depth(n_words: int, branching: int) -> int:
    """Smallest depth L with ``branching ** L >= n_words``."""
    depth = max(1, math.ceil(math.log(n_words) / math.log(branching) - 1e-9))
    while branching**depth < n_words:
        depth += 1
    return depth


#: Largest ``--branching`` of a vocabulary tree: each node runs a k-means of that many
#: centres on at most ``VocabularyTree.max_node_samples`` (5000) descriptors, so past a
#: thousand a node has a handful of descriptors a centre (DBoW's trees use 10); 10^9
#: was refused by the tree as "max_node_samples must be ... >= 1000000000", an option
#: the command does not have.
MAX_BRANCHING = 1000


def check_training_settings(n_words: int, branching: int = 10, per_image: int = 300) -> None:
    """ConfigError (one line) for settings no vocabulary is trained with: checked by the
    commands before their ORB pass, not after it."""
    if n_words < 2:
        raise ConfigError(f"--words must be at least 2, got {n_words}")
    if not 2 <= branching <= MAX_BRANCHING:
        raise ConfigError(f"--branching must be at least 2 and at most {MAX_BRANCHING}, got {branching}")
    if per_image < 0:
        raise ConfigError(f"--per-image must be >= 0, got {per_image}")


def train_vocabulary(
    descriptors: list[np.ndarray],
    n_words: int,
    flat: bool = False,
    branching: int = 10,
    per_image: int = 300,
    seed: int = 0,
):
    """Fit a vocabulary on per-image (N, 32) uint8 descriptor arrays.

    Keeps the first ``per_image`` rows of each array (ORB output is sorted by
    decreasing response when the cell selection is off); 0 keeps all.
    """
    from loopclosure.vocabulary import FlatVocabulary, VocabularyTree

    check_training_settings(n_words, branching, per_image)
    train = [d[:per_image] if per_image else d for d in descriptors]
    train = [d for d in train if len(d)]
    total = sum(len(d) for d in train)
    if total == 0:
        raise InputError("no ORB features found in the images: cannot train a vocabulary")
    if flat:
        if total < n_words:
            raise InputError(
                f"only {total} descriptors for {n_words} words: use fewer --words or more images"
            )
        return FlatVocabulary(n_words=n_words, seed=seed).fit(train)
    return VocabularyTree(branching=branching, depth=tree_depth(n_words, branching), seed=seed).fit(train)


def describe(vocab) -> str:
    """One line naming a vocabulary's kind and size."""
    kind = type(vocab).__name__
    if kind == "VocabularyTree":
        return f"vocabulary tree k={vocab.branching} L={vocab.depth}, {vocab.n_words_} words"
    return f"flat vocabulary, {vocab.n_words_} words"


def vocabulary_doubt(vocab) -> str | None:
    """The warning for a vocabulary whose IDF weights are all 0 (every word in every
    training image: one image, or 10 words on 10 photos), under which every place scores
    0 and no loop is ever found, else None. Trained and used without a word, loop
    detection found nothing and said nothing (nineteenth hostile pass)."""
    idf = np.asarray(getattr(vocab, "idf_", ()), dtype=np.float64)
    if getattr(vocab, "n_training_images_", 0) and idf.size and not np.any(idf > 0.0):
        return (
            f"every IDF weight of the vocabulary is 0: each of its {idf.size} words occurs in "
            f"each of its {vocab.n_training_images_} training images, so every place scores 0 "
            "and no loop can be found; train on more, and more varied, images or with more words"
        )
    return None


def check_vocabulary(vocab, path: Path) -> None:
    """Refuse (InputError naming ``path``) a vocabulary that cannot quantise ORB descriptors."""
    # ORB descriptors are 32-byte binary strings; a float vocabulary cannot quantise them.
    if getattr(vocab, "metric_", None) != "hamming" or getattr(vocab, "descriptor_dim_", None) != 32:
        raise InputError(
            f"vocabulary is not for ORB descriptors (metric "
            f"{getattr(vocab, 'metric_', '?')}, dimension "
            f"{getattr(vocab, 'descriptor_dim_', '?')}; need hamming, 32)",
            path,
        )


@dataclass(frozen=True)
class FolderPlaces:
    """How a folder's images are told apart in time (:mod:`loopclosure.places`).

    Attributes:
        mode: ``"covisibility"``, ``"video"`` or ``"keyframes"``, as resolved.
        chosen: True when ``"auto"`` chose it (from ``median_overlap``).
        median_overlap: median share of features matched between consecutive images.
        timestamps: (N,) seconds (from file names or a KITTI-style ``times.txt``), or None.
    """

    mode: str
    chosen: bool
    median_overlap: float | None
    timestamps: np.ndarray | None

    def describe(self, config, excluded=None) -> str:
        """One line for the summary: the mode, why, and what it excludes (``excluded``:
        the number of older images each query could not return, when known)."""
        if self.mode == "covisibility":
            line = (
                f"covisibility: a query never returns the images sharing >= "
                f"{config.min_shared_tracks} tracked features with it"
            )
            if excluded:
                line += f" (median {np.median(excluded):g}, at most {max(excluded)} images excluded)"
            return (
                line + f"; a closure needs {config.consistency_k} agreeing covisible queries, "
                "or one where the query has no covisible predecessor"
            )
        why = ""
        if self.median_overlap is not None:
            rel = "<" if self.mode == "keyframes" else ">="
            why = f" (median consecutive overlap {self.median_overlap:.2f} {rel} {config.keyframe_overlap:g})"
        how = ("auto: " if self.chosen else "") + self.mode + why
        if self.mode == "keyframes":
            return f"{how}: excluding overlapping predecessors, one verified query suffices"
        if self.timestamps is not None:
            return f"{how}: excluding the last {config.exclude_recent_s:g} s"
        return f"{how}: excluding the last {config.exclude_recent} frames"


def folder_timestamps(paths: list[Path]) -> np.ndarray | None:
    """Seconds per image from the file names (TUM style) or ``../times.txt`` (KITTI), else None."""
    from loopclosure.places import timestamps_from_names

    t = timestamps_from_names(paths)
    if t is not None or not paths:
        return t
    times = paths[0].parent.parent / "times.txt"
    if times.is_file():
        try:
            t = np.loadtxt(times, ndmin=1)
        except ValueError:
            return None  # not a list of numbers: not a timestamp file
        if t.ndim == 1 and len(t) == len(paths) and np.all(np.diff(t) > 0):
            return t
    return None


#: Consecutive pairs the folder commands measure to choose the mode (about 10 ms each).
FOLDER_PROBE_PAIRS = 25


def folder_places(features: list, config, timestamps: np.ndarray | None) -> FolderPlaces:
    """Resolve ``config.mode`` (``[loops]``) on a whole folder from consecutive pairs spread
    over it (all of them up to :data:`FOLDER_PROBE_PAIRS`); ``timestamps`` (seconds, from
    :func:`folder_timestamps`) are kept only when they increase (not a backwards run)."""
    from loopclosure.places import choose_mode, consecutive_overlap

    if timestamps is not None and not np.all(np.diff(timestamps) > 0):
        timestamps = None  # a backwards run: no usable times
    if config.mode == "covisibility":
        return FolderPlaces("covisibility", False, None, timestamps)
    overlaps = []
    if config.mode == "auto" and len(features) > 1:
        # at most FOLDER_PROBE_PAIRS evenly spaced pairs: a median needs no more
        starts = np.unique(np.linspace(0, len(features) - 2, FOLDER_PROBE_PAIRS).astype(int))
        overlaps = [consecutive_overlap(features[k].descriptors, features[k + 1].descriptors) for k in starts]
    mode = choose_mode(config.mode, overlaps, config.keyframe_overlap)
    return FolderPlaces(
        mode, config.mode == "auto", float(np.median(overlaps)) if overlaps else None, timestamps
    )


def detect_loops(
    paths: list[Path],
    detector,
    features: list | None = None,
    progress: bool = False,
    timestamps: np.ndarray | None = None,
):
    """Feed every image (or its precomputed ORB ``features``) to ``detector`` in order.

    ``features`` entries are released as they are used; ``timestamps``
    (seconds) go with the images when given. A stop request (SIGINT, SIGTERM)
    ends the pass at the next image, the closures so far kept in ``detector``.
    Returns ``detector``.
    """
    from frontend.image import load_gray
    from graphslam.pipelines.progress import progress as progress_of

    bar = progress_of(range(len(paths)), desc="loops", unit="img", enabled=progress)
    with interrupt_between_frames() as stop:  # a stop keeps the closures found so far
        for i in bar:
            if stop.requested:
                break
            t = None if timestamps is None else float(timestamps[i])
            if features is None:
                detector.process(load_gray(paths[i]), t)
            else:
                f = features[i]
                features[i] = None  # free memory as we go
                detector.process_features(f.xy_px, f.descriptors, t)
            bar.set_postfix(closures=len(detector.closures), refresh=False)
            signal_hook("step", i)
    bar.close()
    return detector


def sweep_scores(paths: list[Path], features: list, detector, timestamps=None) -> list:
    """``(query, match, normalised score)`` of every verified candidate of a run of
    ``detector`` (built with no score threshold) over precomputed ``features``.

    The precision-recall curve of ``--truth`` sweeps its threshold over these.
    """
    detect_loops(paths, detector, list(features), timestamps=timestamps)
    return [(r.query, r.match, r.normalised_score) for r in detector.records if r.accepted]
