"""The visual front end: track ids stay on one physical point (checked against ground truth)."""

from __future__ import annotations

import numpy as np
import pytest

from frontend.tracking import Tracker
from frontend.tracking_config import TrackerConfig
from slamcore.errors import ConfigError
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from slamcore.spatial.records import PixelPredictions

#: A tracked pixel is "on its point" within this distance of the point's true projection, px.
ON_POINT_PX = 3.0
#: Corners on a depth discontinuity (an object's outline) have no single 3-D point.
EDGE_DEPTH_RATIO = 0.05


@pytest.fixture(scope="module")
def seq():
    """QVGA version of the default synthetic sequence (same scene, half the pixels)."""
    return make_synthetic_images(SyntheticImagesConfig(width=320, height=240, fx=250.0, fy=250.0,
                                                       cx=159.5, cy=119.5))


@pytest.fixture(scope="module")
def frames(seq):
    return [seq.render(k) for k in range(30)]


def _backproject(seq, k, uv, depth):
    """World point under pixel ``uv`` of frame ``k``, or None on a depth edge / nothing."""
    u, v = int(round(uv[0])), int(round(uv[1]))
    win = depth[max(v - 3, 0):v + 4, max(u - 3, 0):u + 4]
    z = float(depth[v, u])
    if not np.all(np.isfinite(win)) or np.ptp(win) > EDGE_DEPTH_RATIO * z:
        return None
    pc = np.linalg.inv(seq.K) @ np.array([uv[0], uv[1], 1.0]) * z
    T = seq.wTc_true[k]
    return T[:3, :3] @ pc + T[:3, 3]


def _errors(seq, frames, tracker, predict=None):
    """Pixel error to the true projection of each tracked observation after its birth."""
    points, errs, ids_per_frame = {}, [], []
    for k, (img, depth) in enumerate(frames):
        pred = None if predict is None else predict(k, points)
        r = tracker.track(img, pred)
        ids_per_frame.append(set(map(int, r.observations.track_ids)))
        new = set(map(int, r.new_ids))
        for tid, uv in zip(map(int, r.observations.track_ids), r.observations.uv_px):
            if tid in new:
                points[tid] = _backproject(seq, k, uv, depth)
            elif points.get(tid) is not None:
                errs.append(float(np.linalg.norm(seq.project(k, points[tid][None])[0][0] - uv)))
    return np.array(errs), ids_per_frame, points


def test_followed_tracks_keep_their_id_on_the_same_3d_point(seq, frames):
    tracker = Tracker(TrackerConfig(detector="harris"), follow_unmapped=True)
    errs, ids, _ = _errors(seq, frames, tracker)
    assert len(errs) > 500  # tracks do live over several frames
    assert np.mean(errs > ON_POINT_PX) < 0.01
    assert np.median(errs) < 0.5
    # ids persist: most points of a frame were already tracked in the one before
    carried = [len(a & b) / max(len(b), 1) for a, b in zip(ids[:-1], ids[1:])]
    assert np.mean(carried[5:]) > 0.6


def test_orb_descriptor_tracks_keep_their_id(seq, frames):
    tracker = Tracker(TrackerConfig(detector="orb"), follow_unmapped=True)
    errs, _, _ = _errors(seq, frames[:15], tracker)
    assert len(errs) > 100
    assert np.mean(errs > ON_POINT_PX) < 0.05


def _truth_predictions(seq, sigma_px=3.0):
    """Back end stand-in: exact projections of the tracks' true points, S = sigma^2 I."""
    def predict(k, points):
        ids = [t for t, p in points.items() if p is not None]
        if k == 0 or not ids:
            return None
        uv, z = seq.project(k, np.array([points[t] for t in ids]))
        W, H = seq.image_size
        ok = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        n = int(ok.sum())
        return PixelPredictions(np.array(ids, dtype=np.int64)[ok], uv[ok],
                                np.tile(np.eye(2) * sigma_px**2, (n, 1, 1)))
    return predict


@pytest.mark.parametrize("detector", ["harris", "fpga"])
def test_active_search_finds_predicted_landmarks_at_their_point(seq, frames, detector):
    # follow off (the EKF's way): ids survive only through active search
    tracker = Tracker(TrackerConfig(detector=detector, max_new_per_frame=10), follow_unmapped=False)
    errs, _, _ = _errors(seq, frames[:20], tracker, predict=_truth_predictions(seq))
    assert len(errs) > 100
    assert np.mean(errs > ON_POINT_PX) < 0.05


def test_active_search_result_for_rerun(seq, frames):
    tracker = Tracker(TrackerConfig(max_new_per_frame=5), follow_unmapped=False)
    predict = _truth_predictions(seq)
    points = {}
    for k, (img, depth) in enumerate(frames[:6]):
        r = tracker.track(img, predict(k, points))
        for tid, uv in zip(map(int, r.new_ids), r.new_uv):
            points[tid] = _backproject(seq, k, uv, depth)
    assert len(r.pred_ids) > 0 and r.n_searched > 0 and r.n_found > 0
    assert r.pred_S.shape == (len(r.pred_ids), 2, 2)
    assert 0.0 < r.image_fraction < 0.5
    found_ids = set(map(int, r.pred_ids[r.found]))
    assert found_ids <= set(map(int, r.observations.track_ids))
    assert np.all(np.isnan(r.found_uv[~r.found]))
    assert len(r.corners) > 20 and r.cell_size_px == 32


def test_search_stops_at_the_back_ends_correction_cap(seq, frames):
    """A back end correcting at most m landmarks gets at most m found; the rest are
    reported unsearched (not missed), largest ellipses searched first."""
    cap = 3
    truth = _truth_predictions(seq)

    def capped(k, points):
        p = truth(k, points)
        if p is None:
            return None
        # ellipses of different sizes so that the order is defined
        S = p.S_px2 * (1.0 + 0.1 * np.arange(len(p)))[:, None, None]
        return PixelPredictions(p.track_ids, p.uv_px, S, max_corrections=cap)

    tracker = Tracker(TrackerConfig(max_new_per_frame=10), follow_unmapped=False)
    points = {}
    checked = 0
    for k, (img, depth) in enumerate(frames[:8]):
        pred = capped(k, points)
        r = tracker.track(img, pred)
        for tid, uv in zip(map(int, r.new_ids), r.new_uv):
            points[tid] = _backproject(seq, k, uv, depth)
        if pred is None or len(r.pred_ids) <= cap:
            continue
        checked += 1
        assert r.n_found <= cap
        unsearched = set(map(int, r.observations.unsearched_ids))
        assert unsearched == set(map(int, r.pred_ids[~r.searched]))
        if r.n_found == cap:
            # searched in decreasing ellipse size: every unsearched one is smaller
            area = np.linalg.det(r.pred_S)
            assert area[~r.searched].max() <= area[r.searched].min()
        else:
            assert not unsearched
    assert checked >= 3


def test_without_following_unmapped_tracks_live_one_frame(seq, frames):
    tracker = Tracker(TrackerConfig(), follow_unmapped=False)
    seen = set()
    for img, _ in frames[:4]:
        r = tracker.track(img)  # no predictions: the back end mapped nothing
        ids = set(map(int, r.observations.track_ids))
        assert ids == set(map(int, r.new_ids)) and not ids & seen
        seen |= ids
    assert tracker.n_tracks == len(r.new_ids)


def test_new_tracks_keep_their_distance(seq, frames):
    cfg = TrackerConfig(min_distance_px=20.0, max_new_per_frame=50)
    tracker = Tracker(cfg, follow_unmapped=True)
    for img, _ in frames[:5]:
        r = tracker.track(img)
        uv = r.observations.uv_px
        new = np.isin(r.observations.track_ids, r.new_ids)
        d = np.linalg.norm(uv[new][:, None] - uv[None], axis=2)
        d[np.arange(new.sum()), np.flatnonzero(new)] = np.inf
        assert d.min() >= cfg.min_distance_px
        assert len(np.unique(r.observations.track_ids)) == len(r.observations)


def test_same_input_same_tracks(seq, frames):
    a, b = Tracker(TrackerConfig()), Tracker(TrackerConfig())
    for img, _ in frames[:6]:
        ra, rb = a.track(img), b.track(img)
        assert np.array_equal(ra.observations.track_ids, rb.observations.track_ids)
        assert np.array_equal(ra.observations.uv_px, rb.observations.uv_px)


def test_bad_configuration_is_refused():
    with pytest.raises(ConfigError, match=r"tracker\.detector must be one of"):
        TrackerConfig(detector="sift")
    # across fields: each value is fine alone, not together
    with pytest.raises(ConfigError, match=r"tracker\.search 'descriptor' does not fit detector"):
        TrackerConfig(detector="harris", search="descriptor")
    with pytest.raises(ConfigError, match=r"tracker\.search 'zncc' does not fit detector 'orb'"):
        TrackerConfig(detector="orb", search="zncc")
    with pytest.raises(ConfigError, match=r"tracker\.max_tracks must be >= 1"):
        TrackerConfig(max_tracks=0)


@pytest.mark.parametrize("field, value", [
    # wrong type
    ("max_tracks", 8.5), ("max_new_per_frame", "20"), ("min_distance_px", "far"),
    ("follow_unmapped", 1), ("follow_window_px", True), ("sigma_px", None), ("detector", 1),
    # out of range
    ("max_tracks", 0), ("max_tracks", 2**24 + 1), ("max_new_per_frame", -1),
    ("min_distance_px", -1.0), ("follow_window_px", 0), ("follow_window_px", 4097),
    ("follow_min_score", 1.5), ("follow_min_margin", -0.1), ("follow_min_margin", 2.5),
    ("max_unmapped_age", 0), ("max_hamming", -1), ("max_hamming", 257), ("sigma_px", 0.0),
    # unknown mode
    ("detector", "sift"), ("search", "brute"), ("patch_update", "first"),
])
def test_config_refuses_a_bad_value_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"^tracker\.{field}\b"):
        TrackerConfig(**{field: value})


@pytest.mark.parametrize("shape", [(1, 1), (1, 640), (640, 1), (2, 2), (3, 2000)])
@pytest.mark.parametrize("detector", ["harris", "orb", "fpga"])
def test_images_too_small_to_correlate_are_tracked_without_an_opencv_error(shape, detector):
    """Third hostile pass: a folder of 1x1 (or 1x640) images crashed the image-motion
    measure (OpenCV's Hanning window needs 2 pixels a side; a strip reduced to 0 rows);
    such images now give no motion measure and, having no corner, no track."""
    rng = np.random.default_rng(0)
    tracker = Tracker(TrackerConfig(detector=detector))
    for _ in range(3):
        r = tracker.track(rng.integers(0, 256, shape).astype(np.uint8))
    assert len(r.observations.track_ids) == 0


def _texture(seed: int, shape=(320, 320)) -> np.ndarray:
    import cv2

    noise = np.random.default_rng(seed).uniform(0, 255, (shape[0] // 4, shape[1] // 4))
    return cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)


def test_orb_landmarks_are_searched_among_every_keypoint_not_only_the_cells_best():
    """ORB's cell selection keeps the strongest corner of each cell for new tracks; a
    landmark is searched for among every keypoint of its ellipse (ORB-SLAM's search by
    projection). A checkerboard pasted far from each landmark, in its cell, wins the
    cell: the landmarks are still found where they are (before: none found)."""
    from frontend.orb import OrbConfig

    base = _texture(5)
    tracker = Tracker(TrackerConfig(detector="orb"), orb=OrbConfig(cell_size_px=160), follow_unmapped=False)
    born = tracker.track(base)
    assert len(born.new_ids) == 4  # one a cell
    frame = base.copy()
    checker = (np.indices((24, 24)).sum(0) // 6 % 2 * 255).astype(np.uint8)
    for u, v in born.new_uv:  # in the cell's quadrant farthest from the landmark
        cu, cv = int(u // 160) * 160, int(v // 160) * 160
        pu, pv = cu + (120 if u - cu < 80 else 40), cv + (120 if v - cv < 80 else 40)
        frame[pv - 12:pv + 12, pu - 12:pu + 12] = checker
    winners = tracker.detector.detect(frame).xy_px
    assert np.min(np.linalg.norm(winners[:, None] - born.new_uv[None], axis=2)) > 20.0
    pred = PixelPredictions(track_ids=born.new_ids, uv_px=born.new_uv,
                            S_px2=np.repeat(4.0 * np.eye(2)[None], len(born.new_ids), axis=0))
    res = tracker.track(frame, pred)
    assert res.found.all()
    np.testing.assert_allclose(res.found_uv, born.new_uv, atol=1e-6)


def test_orb_candidates_come_from_the_same_detection():
    """The ellipses' keypoints and the selected features come from one ORB detection: each
    selected point inside a box is among the candidates with the same descriptor, none
    lies outside the boxes, and no box gives no candidate."""
    from frontend.orb import OrbDetector

    image = _texture(6, (240, 320))
    orb = OrbDetector()
    selected, none = orb.detect_with_candidates(image)
    assert len(none) == 0 and np.array_equal(selected.xy_px, orb.detect(image).xy_px)
    boxes = np.array([[20.0, 20.0, 140.0, 120.0], [200.0, 100.0, 300.0, 220.0]])
    _, cands = orb.detect_with_candidates(image, boxes)
    u, v = cands.xy_px.T
    inside = ((u[:, None] >= boxes[:, 0]) & (u[:, None] <= boxes[:, 2])
              & (v[:, None] >= boxes[:, 1]) & (v[:, None] <= boxes[:, 3])).any(axis=1)
    assert inside.all() and len(cands) > len(selected) / 4
    for p, d in zip(selected.xy_px, selected.descriptors):
        if ((p[0] >= boxes[:, 0]) & (p[0] <= boxes[:, 2]) & (p[1] >= boxes[:, 1]) & (p[1] <= boxes[:, 3])).any():
            same = np.flatnonzero((cands.xy_px == p).all(axis=1))
            assert any(np.array_equal(cands.descriptors[j], d) for j in same)
