"""Places (recent-frame exclusion modes), real-pair verification, the shipped vocabulary,
the a-contrario and coverage measures, and the --truth evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frontend.image import load_gray
from loopclosure.acontrario import hull_coverage, log10_nfa
from loopclosure.detector import LOOP_ORB, LoopDetector, LoopDetectorConfig
from loopclosure.places import choose_mode, consecutive_overlap, recent_window, timestamps_from_names
from loopclosure.verify import GeometricVerifier
from slamcore.errors import InputError
from tests.conftest import SHARED_DATA

DESK = SHARED_DATA / "slambook2_desk" / "images"
KITTI = SHARED_DATA / "kitti07" / "image_0"


def _features(path: Path):
    from frontend.orb import OrbDetector

    return OrbDetector(LOOP_ORB).detect(load_gray(path))


# ----------------------------------------------------------------------------- modes


def test_recent_window_per_mode():
    cfg = LoopDetectorConfig(mode="auto", exclude_recent=4, exclude_recent_s=1.0, keyframe_overlap=0.1)
    # video, frames: the last 4 (fewer at the start)
    assert recent_window(10, "video", cfg, []) == 4
    assert recent_window(2, "video", cfg, []) == 2
    # video, seconds: at 4 Hz, the images less than 1 s older than t_q = 6.25 s
    # are those at 5.5, 5.75 and 6.0 s (5.25 s is exactly 1 s older: allowed)
    t = np.arange(30) * 0.25
    assert recent_window(25, "video", cfg, [], t) == 3
    # keyframes: the previous image, plus predecessors chained by overlap >= 0.1
    overlaps = [0.02, 0.3, 0.5, 0.01, 0.2]  # pairs (0,1) (1,2) (2,3) (3,4) (4,5)
    assert recent_window(5, "keyframes", cfg, overlaps) == 1   # 4; (3,4) at 0.01 breaks the chain
    assert recent_window(4, "keyframes", cfg, overlaps) == 3   # 3, then 2 and 1 linked by 0.5, 0.3
    assert recent_window(2, "keyframes", cfg, overlaps) == 1   # 1; (0,1) at 0.02 breaks it


def test_auto_mode_tells_video_from_a_sparse_folder():
    # measured on real images: KITTI 07 consecutive frames vs the desk photos
    kitti = [_features(KITTI / f"{i:06d}.png").descriptors for i in range(4)]
    desk = [_features(p).descriptors for p in sorted(DESK.glob("*.png"))[:4]]
    ok = [consecutive_overlap(a, b) for a, b in zip(kitti[:-1], kitti[1:])]
    od = [consecutive_overlap(a, b) for a, b in zip(desk[:-1], desk[1:])]
    assert choose_mode("auto", ok, 0.1) == "video"
    assert choose_mode("auto", od, 0.1) == "keyframes"
    assert choose_mode("video", od, 0.1) == "video"  # an explicit mode is kept


def test_timestamps_from_names():
    assert np.allclose(timestamps_from_names([Path("1305031102.175304.png"),
                                              Path("1305031102.211214.png")]),
                       [1305031102.175304, 1305031102.211214])
    assert timestamps_from_names([Path("000001.png"), Path("000002.png")]) is None  # counters
    assert timestamps_from_names([Path("2.5.png"), Path("1.5.png")]) is None  # not increasing


@pytest.mark.parametrize("mode", ["covisibility", "auto"])
def test_desk_folder_gives_its_true_pair_only(mode):
    """The detector as `graphslam loops` runs it (covisibility, the default), and with the
    older auto mode (keyframes here); shipped vocabulary."""
    from loopclosure.shipped import load_shipped_vocabulary

    paths = sorted(DESK.glob("*.png"))
    extra = {"probe_pairs": 9} if mode == "auto" else {}
    det = LoopDetector(load_shipped_vocabulary(), LoopDetectorConfig(mode=mode, **extra))
    for p in paths:
        det.process(load_gray(p))
    assert det.mode == ("keyframes" if mode == "auto" else "covisibility")
    assert [(c.query, c.match) for c in det.closures] == [(9, 0)]


# ----------------------------------------------------------------------------- verification


def test_real_pairs_true_accepted_different_place_rejected():
    desk1, desk10 = _features(DESK / "01.png"), _features(DESK / "10.png")
    kitti = _features(KITTI / "000050.png")
    v = GeometricVerifier()
    ok = v.verify(desk10.xy_px, desk10.descriptors, desk1.xy_px, desk1.descriptors)
    assert ok.accepted, ok.reason
    assert ok.log10_nfa < 0 and ok.coverage >= v.config.min_coverage
    bad = v.verify(desk10.xy_px, desk10.descriptors, kitti.xy_px, kitti.descriptors)
    assert not bad.accepted
    # two desk photos of one scene from different sides: overlap too small for a revisit
    desk3, desk2 = _features(DESK / "03.png"), _features(DESK / "02.png")
    side = v.verify(desk3.xy_px, desk3.descriptors, desk2.xy_px, desk2.descriptors)
    assert not side.accepted


def test_nfa_separates_structure_from_chance():
    rng = np.random.default_rng(0)
    # 40 residuals near 0 among 60 uniform ones in a VGA image: meaningful
    res = np.r_[rng.uniform(0, 0.5, 40), rng.uniform(0, 300, 60)]
    assert log10_nfa(res, "fundamental", 640, 480)[0] < 0
    # all uniform: not meaningful
    assert log10_nfa(rng.uniform(0, 300, 100), "fundamental", 640, 480)[0] > 0
    # 20 good among 60 is meaningful, 20 good among 3000 is not: the relative test
    assert log10_nfa(np.r_[np.full(20, 0.5), rng.uniform(0, 300, 40)], "fundamental", 640, 480)[0] < 0
    assert log10_nfa(np.r_[np.full(20, 0.5), rng.uniform(0, 300, 2980)], "fundamental", 640, 480)[0] > 0


def test_hull_coverage():
    grid = np.stack(np.meshgrid(np.arange(0, 101, 10.0), np.arange(0, 101, 10.0)), -1).reshape(-1, 2)
    half = grid[grid[:, 0] <= 50]
    assert hull_coverage(grid, grid) == pytest.approx(1.0)
    assert hull_coverage(grid, half) == pytest.approx(0.5)
    assert hull_coverage(grid, half[:2]) == 0.0


# ----------------------------------------------------------------------------- vocabulary, truth


def test_shipped_vocabulary_loads():
    from loopclosure.shipped import SHIPPED_VOCABULARY, load_shipped_vocabulary

    v = load_shipped_vocabulary()
    assert v.metric_ == "hamming" and v.descriptor_dim_ == 32
    assert 9000 <= v.n_words_ <= 10000  # k = 10, L = 4
    assert SHIPPED_VOCABULARY.stat().st_size < 2_000_000  # package data stays small
    words = v.transform(_features(DESK / "01.png").descriptors)
    assert len(np.unique(words)) > 100  # a real image spreads over many words


def test_truth_formats_and_scores(tmp_path):
    import cv2

    from graphslam.evaluation.places import pr_curve, read_truth, score

    paths = [Path(f"{i:02d}.png") for i in range(1, 6)]
    (tmp_path / "t.csv").write_text("query,match\n05.png,01.png\n04.png,02.png\n")
    img = np.zeros((5, 5), np.uint8)
    img[4, 0] = img[1, 3] = 1  # (2, 4) given the other way round
    cv2.imwrite(str(tmp_path / "t.png"), img)
    truth = {(4, 0), (3, 1)}
    assert read_truth(tmp_path / "t.csv", paths) == truth
    assert read_truth(tmp_path / "t.png", paths) == truth
    assert score([(4, 0), (3, 0)], truth) == (0.5, 0.5, 1)
    curve = pr_curve([(4, 0, 2.0), (3, 0, 1.0), (3, 1, 0.5)], truth)
    assert [(p.closures, p.precision, p.recall) for p in curve] == [
        (1, 1.0, 0.5), (2, 0.5, 0.5), (3, 2 / 3, 1.0)]
    (tmp_path / "bad.csv").write_text("query,match\n05.png,99.png\n")
    with pytest.raises(InputError, match="99.png") as e:
        read_truth(tmp_path / "bad.csv", paths)
    assert e.value.line == 2
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((3, 3), np.uint8))
    with pytest.raises(InputError, match="5x5"):
        read_truth(tmp_path / "small.png", paths)
