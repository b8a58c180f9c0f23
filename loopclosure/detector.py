"""Loop-closure detector: images in time order -> verified loop closures.

Per image (DBoW2's scheme, Gálvez-López & Tardós, T-RO 2012):

1. ORB features (:class:`frontend.orb.OrbDetector`) and the image's
   bag-of-words vector (:class:`loopclosure.database.BowDatabase`, TF-IDF,
   DBoW2's L1 score in [0, 1]).
2. Prior score ``s_prev``: the L1 score of this image against the previous
   one. Below ``min_prior_score`` the image is too unlike its own neighbour
   for scores to be comparable (blur, a blank wall) and it proposes nothing.
3. Database query, excluding the images the query is *covisible* with
   (``mode = "covisibility"``, the default; :mod:`loopclosure.covisibility`):
   those sharing at least ``min_shared_tracks`` tracked features with it,
   the tracks being, for a folder, ORB features followed over a local map,
   and for a run (``track_ids``) its own tracks or those followed features,
   whichever count is larger (a tracker that keeps 3-7 tracks through a weak
   stretch left frames 4 apart uncovisible: one closed a "loop" between
   them on the synthetic room). They resemble the query because the
   camera still sees what they saw; no window of frames or seconds is
   assumed. The older rules remain as overrides (:mod:`loopclosure.places`):
   ``"video"`` (a window in seconds or frames), ``"keyframes"`` (the
   overlapping predecessors), ``"auto"`` (one of the two from consecutive
   overlap). Each answer's score is normalised, ``eta = s / s_prev``, and
   the best answer with ``eta >= min_normalised_score`` and
   ``s >= min_score`` is the candidate.
4. Consistency over covisible queries (ORB-SLAM's consistent groups): the
   candidate and those of the queries before it that the query is covisible
   with must form a chain in which each match is covisible with the previous
   one (shares ``min_shared_tracks`` tracks, or is the same image); the chain
   must reach ``consistency_k``, or one more than the covisible queries among
   the ``consistency_k - 1`` before it. Video, where consecutive frames are
   covisible, thus asks ``consistency_k`` agreeing queries, and a sparse folder,
   where they are not, one verified query: one rule for both. A query without a
   candidate breaks the chain. (``"video"`` mode: match indices within
   ``consistency_tolerance`` frames; ``"keyframes"``: one query.)
5. Geometric verification (:class:`loopclosure.verify.GeometricVerifier`):
   RANSAC on ORB matches; with ``K`` the relative pose ``query T match``
   (rotation, unit translation). Where the candidate fails, one second view
   of its place (the best other answer covisible with it, ``second_views``)
   is verified instead; the closure then joins the query to that view.

The image is added to the database after its query, so it is never its own
answer. Every query that produced a candidate, or was skipped, leaves a
:class:`CandidateRecord` saying what happened (:meth:`LoopDetector.write_log`
writes them as JSON lines). The defaults favour precision: a false closure can
wreck a map, a missed one only costs accuracy.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from frontend.orb import OrbConfig, OrbDetector
from loopclosure.covisibility import CovisibilityGraph, DescriptorTracker
from loopclosure.places import Mode, choose_mode, consecutive_overlap, recent_window
from loopclosure.verify import GeometricVerifier, PairVerifier, Verification, VerifyConfig
from slamcore.config import Validated, bounded
from slamcore.errors import ConfigError, InputError

__all__ = ["LoopDetectorConfig", "CandidateRecord", "DetectedLoop", "LoopDetector", "LOOP_ORB"]

#: ORB of the loop detector by default (:attr:`LoopDetectorConfig.orb`).
LOOP_ORB = OrbConfig(n_features=1000, cell_size_px=0, per_cell=1, fast_threshold=20)


@dataclass(frozen=True)
class LoopDetectorConfig(Validated):
    """Loop detector settings (config section ``[loops]``).

    Attributes:
        mode: ``"covisibility"`` (default: module docstring, step 3), or an
            override, ``"auto"``, ``"video"`` or ``"keyframes"`` (:mod:`loopclosure.places`).
        min_shared_tracks: tracked features a frame shares with the query for
            the two to be covisible (``"covisibility"`` mode).
        exclude_recent: ``"video"`` mode without timestamps: the most recent images
            never returned by a query (frames); must cover the frames a camera
            needs to leave a place.
        exclude_recent_s: ``"video"`` mode with timestamps: the same window in seconds.
        keyframe_overlap: consecutive-image overlap (share of matched
            features) below which ``"auto"`` chooses keyframes, and from which
            two consecutive keyframes count as overlapping.
        probe_pairs: consecutive pairs ``"auto"`` measures before deciding
            (online; the folder command measures pairs spread over the folder first).
        max_results: database answers examined per query.
        min_prior_score: skip the query when the score against the previous
            image is below this (L1 score, [0, 1]).
        min_normalised_score: smallest ``score / prior score`` of a candidate
            (DBoW2's alpha).
        min_score: smallest raw L1 score of a candidate.
        consistency_k: consecutive queries whose candidates must agree.
        consistency_tolerance: ``"video"`` mode: largest difference (frames)
            between the match indices of two consecutive queries that still agree.
        second_views: ``"covisibility"`` mode: when the candidate's geometry fails,
            verify one second view of its place (the best other answer covisible
            with it; :meth:`LoopDetector._second_view`) before giving up.
        orb: ORB settings of the detector (:class:`frontend.orb.OrbConfig`),
            a ``[loops.orb]`` table in a config file. The default is not the
            tracker's ``[orb]``: 1000 candidates and no per-cell selection
            (``n_features = 1000``, ``cell_size_px = 0``, ``per_cell = 1``,
            ``fast_threshold = 20``, the rest as :class:`OrbConfig`). A
            ``[loops.orb]`` table changes only the keys it writes.
    """

    SECTION: ClassVar[str] = "loops"

    mode: Mode = "covisibility"
    # 20: the verifier's own min_inliers (ORB-SLAM's 20), and above chance:
    # images of different places share a median 8, at most 18, ratio-tested
    # mutual matches among their 500 strongest loop-ORB features (800 pairs
    # of KITTI 07, the desk and the synthetic room, measured)
    min_shared_tracks: int = bounded(20, min=1)
    # 40 frames: at 10-30 Hz, 1.3-4 s, the time a camera takes to leave a place
    # (set on the synthetic sequence, 300 frames for 1.5 laps)
    exclude_recent: int = bounded(40, min=0)
    # 10 s: a walker (1.4 m/s) covers 14 m, less than the shortest loop round a
    # room; a car (10 m/s) 100 m, less than a city block's perimeter
    exclude_recent_s: float = bounded(10.0, min=0.0)
    # Measured (1000-feature loop ORB, 500 strongest compared): consecutive
    # KITTI 07 frames (10 Hz driving) share a median 0.52 of their features,
    # the slambook2 desk photos 0.02 (0.01-0.09); 0.1 is near the geometric
    # mean of the two (0.10), an order of magnitude from each
    keyframe_overlap: float = bounded(0.1, min=0.0, max=1.0)
    probe_pairs: int = bounded(5, min=1, max=1000)
    max_results: int = bounded(10, min=1)
    # DBoW2's L1 score lies in [0, 1]; the normalised score (score / prior) may exceed 1
    min_prior_score: float = bounded(0.01, min=0.0, max=1.0)
    min_normalised_score: float = bounded(0.3, min=0.0)
    min_score: float = bounded(0.0, min=0.0, max=1.0)
    consistency_k: int = bounded(3, min=1)
    consistency_tolerance: int = bounded(3, min=0)
    second_views: bool = True
    orb: OrbConfig = LOOP_ORB

    def __post_init__(self):
        super().__post_init__()
        # a setting the chosen mode does not read is refused, not silently ignored
        used = _MODE_FIELDS[self.mode]
        for name in sorted(set().union(*_MODE_FIELDS.values()) - used):
            if getattr(self, name) != _DEFAULTS[name]:
                modes = [m for m, f in _MODE_FIELDS.items() if name in f]
                raise ConfigError(
                    f"loops.{name} is read only with mode = "
                    f"{' or '.join(repr(m) for m in modes)}, not {self.mode!r}; "
                    "set [loops] mode to use it"
                )


#: The settings only some modes read (``__post_init__`` refuses the others).
_MODE_FIELDS = {
    "covisibility": {"min_shared_tracks", "second_views"},
    "video": {"exclude_recent", "exclude_recent_s", "consistency_tolerance"},
    "keyframes": {"keyframe_overlap"},
    "auto": {
        "exclude_recent",
        "exclude_recent_s",
        "consistency_tolerance",
        "keyframe_overlap",
        "probe_pairs",
    },
}
_DEFAULTS = {f.name: f.default for f in dataclasses.fields(LoopDetectorConfig)}


@dataclass(frozen=True)
class CandidateRecord:
    """The fate of one query (one JSON line of the candidate log).

    ``match`` is None when the query was skipped or had no candidate above the
    thresholds (its best answer is still given in ``best_match``/``score``).
    ``reason`` is None when ``accepted``; otherwise one of: ``"low prior
    score"``, ``"no database answer"``, ``"below threshold"``, ``"not
    temporally consistent (c/k)"``, or the verifier's reason prefixed by
    ``"geometry: "``.
    """

    query: int
    match: int | None
    best_match: int | None
    score: float
    normalised_score: float | None
    prior_score: float | None
    consistency: int
    n_matches: int | None
    n_inliers: int | None
    accepted: bool
    reason: str | None
    #: older images the query could not return (covisible with it, or in its window)
    excluded: int | None = None
    #: the candidate whose geometry failed when ``match`` is its second view
    #: (:attr:`LoopDetectorConfig.second_views`); None otherwise
    second_view_of: int | None = None
    #: which test accepted the views' overlap (:attr:`Verification.accepted_by`) when
    #: ``accepted``; None otherwise
    accepted_by: str | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        for key in ("second_view_of", "accepted_by"):  # the log's lines keep their keys unless used
            if d[key] is None:
                del d[key]
        return d


@dataclass(frozen=True, eq=False)
class DetectedLoop:
    """An accepted closure between image ``query`` and the older image ``match``.

    Attributes:
        query, match: image indices (``match < query``).
        score: DBoW2 L1 score; normalised_score: score / prior score.
        n_inliers: RANSAC inliers of the geometric verification.
        R: (3, 3) rotation of ``query T match`` (``p_query = R p_match + s t``),
            or None without intrinsics; t_unit: (3,) unit translation, or None
            (without intrinsics, or views with too little parallax to observe it:
            :class:`loopclosure.verify.Verification`).
    """

    query: int
    match: int
    score: float
    normalised_score: float
    n_inliers: int
    R: np.ndarray | None = None
    t_unit: np.ndarray | None = None


@dataclass
class _Stored:
    xy: np.ndarray
    descriptors: np.ndarray
    size: tuple[float, float] | None  # (width, height) px, when known


class LoopDetector:
    """Feed images in time order with :meth:`process`; closures come back as found.

    Parameters:
        vocabulary: a fitted vocabulary (:mod:`loopclosure.vocabulary`).
        config: :class:`LoopDetectorConfig` (defaults if None).
        verify_config: :class:`loopclosure.verify.VerifyConfig` of the built-in
            :class:`~loopclosure.verify.GeometricVerifier` (defaults if None).
        verifier: any :class:`~loopclosure.verify.PairVerifier` instead of the
            built-in one (then no ``verify_config``).
        K: (3, 3) intrinsics shared by all images, or None (fundamental matrix,
            no relative pose).
        distortion: OpenCV distortion coefficients, or None.
        database: a :class:`loopclosure.database.BowDatabase`-like object; a new
            ``BowDatabase(vocabulary)`` when None.
        mode: with ``config.mode = "auto"``, ``"video"`` or ``"keyframes"`` as the
            caller resolved it (a folder command measures the whole folder first);
            None lets the detector decide online.

    Attributes after running: ``records`` (list of :class:`CandidateRecord`),
    ``closures`` (list of :class:`DetectedLoop`).
    """

    def __init__(
        self,
        vocabulary,
        config: LoopDetectorConfig | None = None,
        verify_config: VerifyConfig | None = None,
        K: np.ndarray | None = None,
        distortion: np.ndarray | None = None,
        database=None,
        mode: str | None = None,
        verifier: PairVerifier | None = None,
    ):
        self.config = config or LoopDetectorConfig()
        if mode is not None and (self.config.mode != "auto" or mode not in ("video", "keyframes")):
            raise ValueError(f"a resolved mode ({mode!r}) is for mode 'auto' only, as 'video' or 'keyframes'")
        if verifier is not None and verify_config is not None:
            raise ValueError("give a verifier or a verify_config for the built-in one, not both")
        if verifier is not None and not isinstance(verifier, PairVerifier):
            raise TypeError(f"verifier {type(verifier).__name__} has no verify() method")
        self.verifier = GeometricVerifier(verify_config) if verifier is None else verifier
        self.K = None if K is None else np.asarray(K, np.float64)
        self.distortion = distortion
        if database is None:
            from loopclosure.database import BowDatabase

            database = BowDatabase(vocabulary)
        self.database = database
        self.orb = OrbDetector(self.config.orb)
        self.records: list[CandidateRecord] = []
        self.closures: list[DetectedLoop] = []
        self._features: list[_Stored] = []
        self._prev_bow = None
        # (query index, match index) of the recent candidates forming the current chain
        self._chain: list[tuple[int, int]] = []
        #: resolved mode ("video" or "keyframes"); None while "auto" is still measuring
        self.mode: str | None = mode if self.config.mode == "auto" else self.config.mode
        self._overlaps: list[float] = []  # overlap of images k and k+1
        self._times: list[float] | None = None
        #: the tracks of each image: the run's own, or for a folder its ORB features followed
        self.covisibility = CovisibilityGraph()
        self._tracker = DescriptorTracker()
        # beside a run's tracks, its images' features followed as for a folder: a tracker
        # that loses its tracks (a weak stretch) leaves images covisible that still overlap
        self._feature_covisibility = CovisibilityGraph()
        self._own_tracks: bool | None = None  # True: the caller gives track ids
        self._covisible = np.zeros(0, np.int64)  # images the current query is covisible with
        self._linked = np.zeros(0, np.int64)  # the same without the forced previous image
        self._direct: list[np.ndarray] = []  # per image, the older images directly covisible
        #: images each query could not return (covisible, or in the window)
        self.excluded: list[int] = []
        self._n_excluded = 0
        self._record_of: dict[int, int] = {}  # query -> its index in records

    def __len__(self) -> int:
        return len(self._features)

    def features(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """ORB features of image ``i`` as processed: ``(xy_px (N, 2), descriptors (N, 32))``."""
        f = self._features[i]
        return f.xy, f.descriptors

    def process(
        self, image: np.ndarray, timestamp: float | None = None, track_ids: np.ndarray | None = None
    ) -> DetectedLoop | None:
        """Add the next image ((H, W) uint8, its time in seconds if known, the run's
        track ids observed in it if any); returns the closure it makes, if any."""
        f = self.orb.detect(image)
        if f.descriptors is None:  # ORB describes every point it keeps
            raise RuntimeError("the ORB detector returned no descriptors")
        return self.process_features(
            f.xy_px, f.descriptors, timestamp, (float(image.shape[1]), float(image.shape[0])), track_ids
        )

    def process_features(
        self,
        xy_px: np.ndarray,
        descriptors: np.ndarray,
        timestamp: float | None = None,
        image_size: tuple[float, float] | None = None,
        track_ids: np.ndarray | None = None,
    ) -> DetectedLoop | None:
        """Like :meth:`process` with precomputed ORB features ((N, 2) px, (N, 32) uint8);
        ``image_size`` (width, height) px, default the features' extent; ``track_ids``
        ((M,) int) the tracks a visual run observed in this image, for covisibility
        (default: the detector tracks its own features)."""
        i = len(self._features)
        descriptors = np.asarray(descriptors)
        if descriptors.dtype != np.uint8 or descriptors.ndim != 2 or descriptors.shape[1] != 32:
            raise InputError(
                f"descriptors must be (N, 32) uint8 (ORB), got {descriptors.dtype} "
                f"of shape {descriptors.shape}"
            )
        if np.shape(xy_px) != (len(descriptors), 2):
            raise InputError(
                f"xy_px must be ({len(descriptors)}, 2), one point a descriptor, got {np.shape(xy_px)}"
            )
        self._track_places(i, descriptors, timestamp)
        if self.mode == "covisibility":
            self._track_covisibility(i, descriptors, track_ids)
        self._features.append(_Stored(np.asarray(xy_px, np.float64).reshape(-1, 2), descriptors, image_size))
        bow = self.database.bow(descriptors)
        prev, self._prev_bow = self._prev_bow, bow
        loop = self._query(i, bow, prev)  # before adding: an image never answers itself
        added = self.database.add(bow)
        if added != i:  # records and closures use our numbering; the database must agree
            raise RuntimeError(f"database gave id {added} to image {i}")
        return loop

    def _track_places(self, i: int, descriptors: np.ndarray, timestamp: float | None) -> None:
        """Timestamps, consecutive overlaps (while they matter) and the resolved mode."""
        if (timestamp is None) != (self._times is None) and i > 0:
            raise ValueError("give a timestamp for every image or for none")
        if timestamp is not None:
            self._times = (self._times or []) + [float(timestamp)]
        if i > 0 and self.mode not in ("video", "covisibility"):  # only auto and keyframes use them
            self._overlaps.append(consecutive_overlap(self._features[-1].descriptors, descriptors))
        if self.mode is None and len(self._overlaps) >= self.config.probe_pairs:
            self.mode = choose_mode("auto", self._overlaps, self.config.keyframe_overlap)

    def _track_covisibility(self, i: int, descriptors: np.ndarray, track_ids) -> None:
        """The images image i is covisible with (:mod:`loopclosure.covisibility`)."""
        if i > 0 and (track_ids is not None) != self._own_tracks:
            raise ValueError("give track ids for every image or for none")
        self._own_tracks = track_ids is not None
        # the local map: tracks the previous image's covisible ones saw
        local = np.zeros(0, np.int64) if i == 0 else np.append(self._direct[-1], i - 1)
        followed = self._tracker.track(descriptors, local)
        self.covisibility.add(followed if track_ids is None else track_ids)
        shared = self.covisibility.shared(i)  # once a frame: the covisible sets follow from it
        if track_ids is not None:
            # covisible by either measure (the larger count, not the sum: the same features)
            self._feature_covisibility.add(followed)
            shared = np.maximum(shared, self._feature_covisibility.shared(i))
        self._linked = np.flatnonzero(shared >= self.config.min_shared_tracks)
        self._direct.append(self.covisibility.covisible(i, self.config.min_shared_tracks, shared))
        self._covisible = self.covisibility.local_map(self._direct[-1], self._direct)

    def _shared_between(self, a: int, b: int) -> int:
        """Features images ``a`` and ``b`` both saw: tracks, or followed features for a run."""
        n = self.covisibility.shared_between(a, b)
        return max(n, self._feature_covisibility.shared_between(a, b)) if self._own_tracks else n

    def _window(self, i: int) -> int | None:
        """Recent images excluded from image i's query; None while the mode is undecided."""
        if self.mode is None:
            return None
        return recent_window(i, self.mode, self.config, self._overlaps, self._times)

    def _answers(self, i: int, bow) -> list[tuple[int, float]] | None:
        """Database answers image i may have (best first), or None when every older
        image is excluded; sets ``_n_excluded``."""
        c = self.config
        if self.mode == "covisibility":
            excluded = self._covisible
            if len(excluded) >= i:
                return None
            self._n_excluded = len(excluded)
            skip = set(excluded.tolist())
            # ask for enough answers that max_results survive the exclusion
            raw = self.database.query(bow, max_results=c.max_results + len(excluded))
            return [(m, s) for m, s in raw if m not in skip][: c.max_results]
        window = self._window(i)
        if window is None or len(self.database) <= window:
            return None
        self._n_excluded = window
        return self.database.query(bow, max_results=c.max_results, exclude_recent=window)

    def _consistent(self, i: int, match: int) -> tuple[int, int]:
        """Extend or restart the chain of agreeing candidates with ``(i, match)``;
        returns (chain length, length needed) (module docstring, step 4)."""
        c = self.config
        if self._chain:
            q_last, m_last = self._chain[-1]
            if self.mode == "covisibility":
                agree = bool(np.isin(q_last, self._covisible)) and (
                    m_last == match or self._shared_between(m_last, match) >= c.min_shared_tracks
                )
            else:
                agree = q_last == i - 1 and abs(m_last - match) <= c.consistency_tolerance
            if not agree:
                self._chain.clear()
        self._chain.append((i, match))
        if self.mode == "covisibility":
            before = np.count_nonzero(self._linked >= i - c.consistency_k + 1)
            need = min(c.consistency_k, 1 + int(before))
        else:  # keyframes: consecutive queries see different places, one query must do
            need = 1 if self.mode == "keyframes" else c.consistency_k
        return len(self._chain), need

    def _query(self, i: int, bow, prev) -> DetectedLoop | None:
        c = self.config
        answers = self._answers(i, bow)
        if answers is None:
            return None  # nothing old enough to be a loop: no record, nothing happened
        self.excluded.append(self._n_excluded)
        prior = None if prev is None else float(self.database.score(bow, prev))
        best_match, best_score = (answers[0][0], float(answers[0][1])) if answers else (None, 0.0)
        # a zero prior (the previous image shares no word) normalises nothing, whatever
        # min_prior_score allows (0 divided every score by it)
        if prior is None or prior < c.min_prior_score or prior <= 0.0:
            self._chain.clear()
            self._record(i, None, best_match, best_score, None, prior, 0, None, "low prior score")
            return None
        if not answers:
            self._chain.clear()
            self._record(i, None, None, 0.0, None, prior, 0, None, "no database answer")
            return None
        # Answers come best first; the first passing both thresholds is the candidate.
        cand = next(((m, float(s)) for m, s in answers if self._passes(s, prior)), None)
        if cand is None:
            self._chain.clear()
            self._record(
                i, None, best_match, best_score, best_score / prior, prior, 0, None, "below threshold"
            )
            return None
        match, score = cand
        eta = score / prior
        n_chain, need = self._consistent(i, match)
        if n_chain < need:
            reason = f"not temporally consistent ({n_chain}/{need})"
            self._record(i, match, best_match, score, eta, prior, n_chain, None, reason)
            return None
        v: Verification = self._verify(i, match)
        first = None
        if not v.accepted:
            second = self._second_view(i, match, answers, prior)
            if second is None:
                self._record(i, match, best_match, score, eta, prior, n_chain, v, f"geometry: {v.reason}")
                return None
            first, (match, score, v) = match, second
            eta = score / prior
        self._record(i, match, best_match, score, eta, prior, n_chain, v, None, first)
        if self.mode == "covisibility":
            self._confirm_earlier(n_chain)
        loop = DetectedLoop(i, match, score, eta, v.n_inliers, v.R, v.t_unit)
        self.closures.append(loop)
        return loop

    def _passes(self, score: float, prior: float) -> bool:
        """An answer's raw and normalised scores meet the candidate thresholds (prior > 0)."""
        return score >= self.config.min_score and score / prior >= self.config.min_normalised_score

    def _verify(self, i: int, m: int) -> Verification:
        """Image ``i`` (the query) against the older image ``m``."""
        a, b = self._features[i], self._features[m]
        return self.verifier.verify(
            a.xy, a.descriptors, b.xy, b.descriptors, self.K, self.distortion, a.size, b.size
        )

    def _second_view(
        self, i: int, match: int, answers: list[tuple[int, float]], prior: float
    ) -> tuple[int, float, Verification] | None:
        """The candidate ``match`` failed its geometry: ``(m, score, verification)`` of a
        second view of its place when that one verifies, else None. The second view is
        the query's best database answer after ``match`` that passes the same score
        thresholds and is covisible with ``match`` (the same place seen a little
        earlier or later; ORB-SLAM verifies the candidates of a consistent group in
        turn). One view, one more verification: each is a chance for a false
        geometry to pass, so the exposure stays at two per query. A revisit a few
        metres off the first pass's frames is often refused by the nearest view's
        coverage and verified from its neighbour (KITTI 07 driven twice at 1/8 of
        its rate: 16 of 20 revisits recalled without the second view, 19 with it).
        Trying every covisible answer instead recalled 19 too, and at 1/10 joined
        frames 12 m apart (a right pose, but beyond the benchmark's 5 m)."""
        c = self.config
        if self.mode != "covisibility" or not c.second_views:
            return None
        for m, s in answers:  # best first
            if m == match or not self._passes(s, prior):
                continue
            if self._shared_between(m, match) >= c.min_shared_tracks:
                v = self._verify(i, m)
                return (m, float(s), v) if v.accepted else None
        return None

    def _confirm_earlier(self, n_chain: int) -> None:
        """The chain now agrees: its earlier queries' candidates, held back only for want
        of agreement, are as supported as the last one; each that passes its own
        geometric verification becomes a closure too (the first images of a revisit
        are not lost; they come before the closure returned for this image)."""
        for q, m in self._chain[:-1]:
            at = self._record_of.get(q)
            if at is None:
                continue
            rec = self.records[at]
            if rec.match != m or not (rec.reason or "").startswith("not temporally"):
                continue
            v = self._verify(q, m)
            self.records[at] = dataclasses.replace(
                rec,
                consistency=n_chain,
                n_matches=int(v.n_matches),
                n_inliers=int(v.n_inliers),
                accepted=v.accepted,
                reason=None if v.accepted else f"geometry: {v.reason}",
            )
            if v.accepted:
                self.closures.append(
                    DetectedLoop(q, m, rec.score, rec.normalised_score or 0.0, v.n_inliers, v.R, v.t_unit)
                )

    def _record(
        self,
        i,
        match,
        best_match,
        score,
        eta,
        prior,
        n_chain,
        v: Verification | None,
        reason: str | None,
        second_view_of: int | None = None,
    ) -> None:
        self._record_of[int(i)] = len(self.records)
        self.records.append(
            CandidateRecord(
                query=int(i),
                match=None if match is None else int(match),
                best_match=None if best_match is None else int(best_match),
                score=float(score),
                normalised_score=None if eta is None else float(eta),
                prior_score=None if prior is None else float(prior),
                consistency=int(n_chain),
                n_matches=None if v is None else int(v.n_matches),
                n_inliers=None if v is None else int(v.n_inliers),
                accepted=reason is None,
                reason=reason,
                excluded=int(self._n_excluded),
                second_view_of=second_view_of,
                accepted_by=None if v is None or reason is not None else v.accepted_by,
            )
        )

    def run(
        self, images: Iterable[np.ndarray], progress: Callable[[Iterable], Iterable] | None = None
    ) -> list[DetectedLoop]:
        """Process every image of ``images`` (in time order); returns all accepted closures.

        ``progress`` wraps the iterable (e.g. ``tqdm``) when given.
        """
        for img in progress(images) if progress else images:
            self.process(img)
        return list(self.closures)

    def write_log(self, path: str | Path) -> Path:
        """Write every :class:`CandidateRecord` as one JSON object per line."""
        path = Path(path)
        with path.open("w", encoding="utf-8") as fh:
            for r in self.records:
                fh.write(json.dumps(r.to_dict()) + "\n")
        return path
