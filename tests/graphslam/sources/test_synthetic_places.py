"""The synthetic room's ground truth of places (graphslam.sources.spatial.synthetic_images):
the hard revisit pairs a detector must find lie inside the soft truth (frames that see the
same place), and frames facing other walls are not the same place."""

from __future__ import annotations

import pytest

from graphslam.sources.spatial.synthetic_images import make_synthetic_images


@pytest.fixture(scope="module")
def room():
    return make_synthetic_images()


def test_every_revisit_pair_sees_the_same_place(room):
    pairs = room.revisit_pairs[:: max(1, len(room.revisit_pairs) // 40)]  # 40 spread over the list
    assert pairs and all(room.same_place(i, j) for i, j in pairs)


def test_views_of_other_walls_are_not_the_same_place(room):
    # frame 0 faces +x; frames 75 and 100 face +y and -x (turned 90 and 180 deg)
    assert room.shared_view(0, 0) == 1.0
    assert room.shared_view(0, 75) < 0.05 and not room.same_place(0, 75)
    assert room.shared_view(0, 100) == 0.0 and not room.same_place(0, 100)


def test_a_view_turned_from_a_revisit_still_sees_the_same_place(room):
    """(196, 0): 0.54 m and 21 deg apart, outside the revisit rule's 1 m and 10 deg; 81 %
    of the points frame 196 sees are seen by frame 0 (measured)."""
    assert (0, 196) not in set(room.revisit_pairs)
    assert room.shared_view(196, 0) == pytest.approx(0.81, abs=0.02)
    assert room.same_place(196, 0)


def test_a_later_visit_is_the_same_place_seen_after_the_sequences_gap(room):
    """(54, 50): a neighbour sees the same place because the camera has not left it."""
    assert room.same_place(54, 50) and not room.later_visit(54, 50)
    assert room.later_visit(196, 0)  # the turned view of the revisit, 196 frames on
    assert not room.later_visit(100, 0)  # far enough apart, another wall
