"""Covisibility instead of a frame window (issue 33): the graph, the folder tracker, and the
detector on revisits that come back sooner than the old 40-frame window."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from frontend.orb import OrbDetector
from loopclosure.covisibility import CovisibilityGraph, DescriptorTracker
from loopclosure.detector import LoopDetector, LoopDetectorConfig
from loopclosure.verify import VerifyConfig


def test_graph_counts_shared_tracks_and_always_keeps_the_previous_frame():
    g = CovisibilityGraph()
    g.add([1, 2, 3, 4])
    g.add([3, 4, 5])
    g.add([9])          # a frame sharing nothing
    g.add([1, 3, 4, 9])
    assert g.shared(3).tolist() == [3, 2, 1]
    assert g.shared_between(0, 3) == 3
    assert g.covisible(3, 2).tolist() == [0, 1, 2]   # 2 is the previous frame
    assert g.covisible(2, 1).tolist() == [1]         # shares nothing, still the previous
    assert g.covisible(0, 1).tolist() == []


def test_local_map_reaches_two_links_and_no_further():
    # a chain 0 - 1 - 2 - 3 - 4 where only neighbours share tracks
    g, direct = CovisibilityGraph(), []
    for k in range(5):
        g.add([10 * k + j for j in range(5)] + [10 * (k - 1) + j for j in range(5)])
        direct.append(g.covisible(k, 5))
    assert direct[4].tolist() == [3]
    assert g.local_map(direct[4], direct).tolist() == [2, 3]   # 3, and 3's neighbour 2; not 1


def test_tracker_follows_features_within_the_local_map_only():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    tr = DescriptorTracker()
    ids0 = tr.track(a, np.zeros(0, np.int64))
    assert ids0.tolist() == list(range(60))
    ids1 = tr.track(a, np.array([0]))                    # the same features again
    assert ids1.tolist() == ids0.tolist()
    ids2 = tr.track(b, np.array([1]))                    # other features: new tracks
    assert set(ids2.tolist()).isdisjoint(ids0.tolist())
    ids3 = tr.track(a, np.array([2]))                    # a's tracks left the local map
    assert set(ids3.tolist()).isdisjoint(ids0.tolist())
    assert tr.n_tracks == 180


def test_track_ids_are_given_for_every_image_or_none():
    from loopclosure.shipped import load_shipped_vocabulary

    rng = np.random.default_rng(1)
    det = LoopDetector(load_shipped_vocabulary())
    xy = rng.uniform(0, 600, (50, 2))
    d = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    det.process_features(xy, d, track_ids=np.arange(50))
    with pytest.raises(ValueError, match="track ids"):
        det.process_features(xy, d)


@pytest.fixture(scope="module")
def synthetic_features():
    from graphslam.sources.spatial.synthetic_images import (
        SyntheticImagesConfig, make_synthetic_images,
    )

    seq = make_synthetic_images(SyntheticImagesConfig(n_frames=100))
    orb = OrbDetector(LoopDetectorConfig().orb)
    return seq, [orb.detect(seq.load(i)) for i in range(len(seq.image_paths))]


def _closures(feats, mode, K):
    from loopclosure.shipped import load_shipped_vocabulary

    det = LoopDetector(load_shipped_vocabulary(), dataclasses.replace(LoopDetectorConfig(), mode=mode),
                       K=K)
    for f in feats:
        det.process_features(f.xy_px, f.descriptors)
    return det


def test_revisit_inside_the_old_window_is_found(synthetic_features):
    """The 100-frame synthetic sequence taken every 4th frame: the revisit begins about
    17 frames after the first pass, inside the old 40-frame window, which finds nothing;
    covisibility finds nearly every revisit frame, none of them wrong."""
    seq, feats = synthetic_features
    idx = np.arange(0, len(feats), 4)
    sub = [feats[k] for k in idx]
    partners = {}
    for i, j in seq.revisit_pairs:
        if i % 4 == 0 and j % 4 == 0:
            partners.setdefault(j // 4, set()).add(i // 4)
    assert partners and min(partners) - max(max(p) for p in partners.values()) < 40
    assert _closures(sub, "video", seq.K).closures == []
    det = _closures(sub, "covisibility", seq.K)
    tol = 1  # subsampled frames: 4 original frames
    true = [any(abs(c.match - i) <= tol for j in range(c.query - tol, c.query + tol + 1)
                for i in partners.get(j, ())) for c in det.closures]
    assert all(true), [(c.query, c.match) for c in det.closures]
    recalled = {c.query for c in det.closures} & set(partners)
    assert len(recalled) >= 0.8 * len(partners)


def test_earlier_queries_of_a_confirmed_chain_become_closures(synthetic_features):
    """Consistency holds the first queries of a revisit back; once the chain agrees, they
    are verified and kept (their records say so), so a revisit starts where it starts with
    one query (consistency_k = 1), not k - 1 queries later."""
    seq, feats = synthetic_features
    det = _closures(feats, "covisibility", seq.K)
    k = det.config.consistency_k
    assert k >= 2
    first = min(c.query for c in det.closures)
    from loopclosure.shipped import load_shipped_vocabulary

    one = LoopDetector(load_shipped_vocabulary(), dataclasses.replace(det.config, consistency_k=1),
                       K=seq.K)
    for f in feats:
        one.process_features(f.xy_px, f.descriptors)
    assert first == min(c.query for c in one.closures)
    rec = {r.query: r for r in det.records}
    assert rec[first].accepted and rec[first].reason is None and rec[first].consistency >= k
    assert len({c.query for c in det.closures}) == len(det.closures)  # one closure per query


def test_a_setting_the_mode_does_not_read_is_refused():
    from slamcore.errors import ConfigError

    with pytest.raises(ConfigError, match=r"loops\.exclude_recent is read only with mode = 'video'"):
        LoopDetectorConfig(exclude_recent=20)  # the default mode, covisibility, has no window
    with pytest.raises(ConfigError, match=r"loops\.min_shared_tracks is read only"):
        LoopDetectorConfig(mode="video", min_shared_tracks=10)
    with pytest.raises(ConfigError, match=r"loops\.keyframe_overlap"):
        LoopDetectorConfig(mode="video", keyframe_overlap=0.2)
    assert LoopDetectorConfig(mode="auto", exclude_recent=20, keyframe_overlap=0.2).exclude_recent == 20
    with pytest.raises(ValueError, match="resolved mode"):
        LoopDetector(None, LoopDetectorConfig(), mode="video")


# --- second views: the candidate's place seen from a neighbour (detector._second_view) ------


def _run_second_view(answers: dict, accept: set, **cfg):
    """Images 0-2 one place (neighbours share 20 tracks, 0 and 2 only 10), 3-6 another,
    7 back at the first with tracks of its own; the database answers and the verifier
    are scripted (tests/loopclosure/test_loop_detector.py)."""
    from tests.loopclosure.test_loop_detector import ScriptedDatabase, StubVerifier

    tracks = [np.arange(10 * k, 10 * k + 30) for k in range(3)]
    tracks += [np.arange(100 + 10 * k, 130 + 10 * k) for k in range(4)] + [np.arange(1000, 1030)]
    config = LoopDetectorConfig(consistency_k=1, **cfg)
    det = LoopDetector(None, config, database=ScriptedDatabase(answers, {}), verifier=StubVerifier(accept))
    desc = np.zeros((1, 32), np.uint8)
    for i, t in enumerate(tracks):
        det.process_features(np.array([[float(i), 0.0]]), desc, track_ids=t)
    return det


def test_a_failed_candidate_is_verified_from_a_second_view_of_its_place():
    det = _run_second_view({7: [(1, 0.4), (2, 0.35), (0, 0.3)]}, accept={(7, 2)})
    assert [(c.query, c.match) for c in det.closures] == [(7, 2)]
    assert det.verifier.calls == [(7, 1), (7, 2)]
    rec = det.records[-1]
    assert rec.accepted and rec.match == 2 and rec.second_view_of == 1 and rec.best_match == 1
    assert rec.score == pytest.approx(0.35) and rec.to_dict()["second_view_of"] == 1
    assert rec.to_dict()["accepted_by"] == "coverage"  # the verifier's test that accepted it
    # the log's other lines keep the keys they had before second views
    assert len(det.records) > 1 and all("second_view_of" not in r.to_dict() for r in det.records[:-1])
    assert all("accepted_by" not in r.to_dict() for r in det.records[:-1])  # none accepted


def test_only_one_second_view_and_only_one_covisible_with_the_candidate():
    # 2 is the second view (covisible with 1) and fails: 0 is not tried although it would pass
    det = _run_second_view({7: [(1, 0.4), (2, 0.35), (0, 0.3)]}, accept={(7, 0)})
    assert det.closures == [] and det.verifier.calls == [(7, 1), (7, 2)]
    assert det.records[-1].reason.startswith("geometry: ") and det.records[-1].match == 1
    # 5 answers next but sees another place (shares no track with 1): no second view
    det = _run_second_view({7: [(1, 0.4), (5, 0.35)]}, accept={(7, 5)})
    assert det.closures == [] and det.verifier.calls == [(7, 1)]


def test_second_views_off_and_answers_below_the_thresholds_are_not_tried():
    det = _run_second_view({7: [(1, 0.4), (2, 0.35)]}, accept={(7, 2)}, second_views=False)
    assert det.closures == [] and det.verifier.calls == [(7, 1)]
    # a second view must pass the candidate's thresholds (0.1 / 0.5 prior < 0.3 normalised)
    det = _run_second_view({7: [(1, 0.4), (2, 0.1)]}, accept={(7, 2)})
    assert det.closures == [] and det.verifier.calls == [(7, 1)]
    from slamcore.errors import ConfigError

    with pytest.raises(ConfigError, match=r"loops\.second_views is read only"):
        LoopDetectorConfig(mode="video", second_views=False)


#: KITTI 07 driven twice: a closure is true when it joins the two passes this close (m)
#: (benchmarks/bench_loop_revisit.py, NEAR_M of benchmarks/loop_real.py).
TRUE_WITHIN_M = 5.0
#: Second-pass frames with a first-pass frame this close that must be recalled, of 20,
#: by the verifier without its decisive share (measured 19 with second views, 16
#: without), and by the defaults (measured 20).
MIN_RECALLED_OF_20 = 18
MIN_RECALLED_OF_20_DEFAULTS = 19


@pytest.mark.slow
def test_kitti_driven_twice_at_every_8th_frame_second_views_recall_without_a_false_closure(shared_data):
    """Issue 33's held-out case in small: a route driven again from other images (the
    second pass starts 4 frames later), 20 frames after the first pass."""
    from frontend.image import load_gray
    from loopclosure.shipped import load_shipped_vocabulary
    from tests.kitti import kitti07

    root, K, wTc = kitti07(shared_data)
    first, second = np.arange(0, 160, 8), np.arange(4, 160, 8)
    order = np.concatenate([first, second])
    orb = OrbDetector(LoopDetectorConfig().orb)
    feats = {int(k): orb.detect(load_gray(root / "image_0" / f"{k:06d}.png")) for k in order}
    pos = wTc[:, :3, 3]
    near = np.linalg.norm(pos[second][:, None] - pos[first][None], axis=2).min(axis=1) <= TRUE_WITHIN_M
    assert near.sum() == 20
    recalled = {}
    runs = {"defaults": (True, VerifyConfig()), True: (True, VerifyConfig(decisive_share=0.0)),
            False: (False, VerifyConfig(decisive_share=0.0))}
    for run, (second_views, verify) in runs.items():
        det = LoopDetector(load_shipped_vocabulary(), LoopDetectorConfig(second_views=second_views), verify, K=K)
        for k in order:
            det.process_features(feats[int(k)].xy_px, feats[int(k)].descriptors)
        for c in det.closures:
            q, m = int(order[c.query]), int(order[c.match])
            assert c.query >= len(first) > c.match, (q, m)  # across the passes
            assert np.linalg.norm(pos[q] - pos[m]) <= TRUE_WITHIN_M, (q, m)
        recalled[run] = {c.query - len(first) for c in det.closures} & set(np.flatnonzero(near))
    assert len(recalled[True]) >= MIN_RECALLED_OF_20 > len(recalled[False])
    assert len(recalled["defaults"]) >= MIN_RECALLED_OF_20_DEFAULTS


@pytest.mark.parametrize("same_view", [True, False])
def test_a_run_whose_tracker_lost_its_tracks_still_excludes_the_frames_its_images_share(same_view):
    """A run's tracks (``track_ids``) new in every frame, as through a weak stretch of
    tracking: images that still show the same features stay covisible by the features
    followed as for a folder, so the query's old neighbour is no answer; images that share
    nothing are answers, verified (synthetic room, local map: frame 54 closed a "loop" with
    frame 50 by the run's 3-7 tracks alone)."""
    from tests.loopclosure.test_loop_detector import ScriptedDatabase, StubVerifier

    rng = np.random.default_rng(3)
    view = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    det = LoopDetector(None, LoopDetectorConfig(consistency_k=1),
                       database=ScriptedDatabase({5: [(0, 0.9)]}, {}), verifier=StubVerifier({(5, 0)}))
    for i in range(6):
        desc = view if same_view else rng.integers(0, 256, (60, 32), dtype=np.uint8)
        det.process_features(np.c_[np.full(60, float(i)), np.arange(60.0)], desc,
                             track_ids=np.arange(100 * i, 100 * i + 60))
    if same_view:
        assert det.closures == [] and det.verifier.calls == []
    else:
        assert [(c.query, c.match) for c in det.closures] == [(5, 0)]
