"""The verifier contract (loopclosure.verify.PairVerifier), written once and run on
every implementation, and its injection into the loop detector.

A verifier answers whether two images' features show one place: a
:class:`~loopclosure.verify.Verification` whose fields agree with each other
(a reason exactly when rejected, inlier pairs that index the features, a
rotation where a relative pose is given), the same answer twice, a true pair of
real images accepted and a pair of different places rejected.
"""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.detector import LoopDetector
from loopclosure.verify import GeometricVerifier, PairVerifier, Verification
# a fixture: the same KITTI 07 ORB features
from tests.loopclosure.test_verify import kitti  # noqa: F401

#: Every verifier the toolkit ships (a new one is added here and passes the contract).
IMPLEMENTATIONS = [GeometricVerifier]
#: KITTI 07 frames 3 apart (about 3 m at the start): one place, seen twice.
SAME_PLACE = (50, 53)
#: KITTI 07 frames 0 and 150: different streets.
DIFFERENT_PLACES = (0, 150)
#: |det R - 1| and ||R^T R - I|| of a returned rotation (float64 round-off).
ROTATION_TOL = 1e-9


def check_consistent(v: Verification, n_a: int, n_b: int) -> None:
    assert isinstance(v, Verification)
    assert (v.reason is None) == v.accepted
    assert 0 <= v.n_inliers and 0.0 <= v.inlier_ratio <= 1.0
    pairs = np.asarray(v.inlier_pairs)
    assert pairs.dtype.kind == "i" and pairs.ndim == 2 and pairs.shape[1] == 2
    if pairs.size:
        assert pairs[:, 0].min() >= 0 and pairs[:, 0].max() < n_a
        assert pairs[:, 1].min() >= 0 and pairs[:, 1].max() < n_b
    if v.R is not None:
        assert abs(np.linalg.det(v.R) - 1.0) < ROTATION_TOL
        assert np.linalg.norm(v.R.T @ v.R - np.eye(3)) < ROTATION_TOL


@pytest.mark.parametrize("make", IMPLEMENTATIONS)
def test_is_a_pair_verifier(make):
    assert isinstance(make(), PairVerifier)


@pytest.mark.parametrize("make", IMPLEMENTATIONS)
@pytest.mark.parametrize("pair, same", [(SAME_PLACE, True), (DIFFERENT_PLACES, False)])
def test_real_pairs(make, kitti, pair, same):  # noqa: F811 (the imported fixture)
    K, _, features = kitti
    a, b = features(pair[0]), features(pair[1])
    verifier = make()
    first = verifier.verify(a.xy_px, a.descriptors, b.xy_px, b.descriptors, K)
    again = verifier.verify(a.xy_px, a.descriptors, b.xy_px, b.descriptors, K)
    check_consistent(first, len(a.xy_px), len(b.xy_px))
    assert first.accepted == same, first.reason
    assert (again.accepted, again.n_inliers) == (first.accepted, first.n_inliers)
    np.testing.assert_array_equal(again.inlier_pairs, first.inlier_pairs)


@pytest.mark.parametrize("make", IMPLEMENTATIONS)
def test_no_features_is_a_rejection_not_an_error(make):
    empty_xy, empty_desc = np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    v = make().verify(empty_xy, empty_desc, empty_xy, empty_desc)
    check_consistent(v, 0, 0)
    assert not v.accepted


class Refuser:
    """A verifier of another kind: rejects everything, and counts."""

    def __init__(self):
        self.calls = 0

    def verify(self, xy_a, desc_a, xy_b, desc_b, K=None, distortion=None, size_a=None,
               size_b=None) -> Verification:
        self.calls += 1
        return Verification(False, "refused", "none", 0, 0, 0.0, None, None,
                            np.zeros((0, 2), np.int64))


def test_the_detector_uses_the_injected_verifier():
    refuser = Refuser()
    detector = LoopDetector(vocabulary=None, database=object(), verifier=refuser)
    assert detector.verifier is refuser


def test_a_verifier_and_a_verify_config_together_are_refused():
    from loopclosure.verify import VerifyConfig

    with pytest.raises(ValueError, match="not both"):
        LoopDetector(vocabulary=None, database=object(), verifier=Refuser(),
                     verify_config=VerifyConfig())
    with pytest.raises(TypeError, match="no verify"):
        LoopDetector(vocabulary=None, database=object(), verifier=object())
