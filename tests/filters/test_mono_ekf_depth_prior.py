"""The monocular EKF's inverse-distance prior of new landmarks taken from the map
(``[mono_ekf] depth_prior = "map"``) and the inverse distances it reads."""

from __future__ import annotations

import numpy as np
import pytest

from filters import landmark_params as lp
from filters.mono_ekf_config import MonoEkfConfig
from filters.mono_ekf_map import inverse_distances
from tests.filters.test_mono_ekf import (
    IMAGE_SIZE, K, landmark_in_view, loop_world, random_pose, run_filter,
)

#: Inverse distance vs 1 / |p - c| of the Euclidean point, 1/m.
INV_DIST_TOL = 1e-12
#: A new landmark's prior (mean and std) vs the median / spread recomputed here, 1/m.
PRIOR_TOL = 1e-9
#: The synthetic loop's scene has no point nearer than 2.5 m.
SCENE_MIN_DEPTH_M = 2.0


def padded_state(landmarks: list[np.ndarray], kinds: list[int], camera: np.ndarray):
    """A state ``x`` (camera position first) holding the padded landmarks, and its ``idx``."""
    x = [camera]
    idx, o = [], 3
    for L, kind in zip(landmarks, kinds):
        s = lp.SIZE[kind]
        x.append(L[:s])
        idx.append([o + j if j < s else o for j in range(lp.PAD)])  # padding repeats the first
        o += s
    return np.concatenate(x), np.array(idx, dtype=np.int64)


def test_inverse_distances_match_the_euclidean_points():
    rng = np.random.default_rng(3)
    p, q = random_pose(rng)
    kinds = [lp.IDP, lp.AHP, lp.EUCLIDEAN] * 4
    Ls = [landmark_in_view(rng, k, p, q) for k in kinds]
    camera = p + rng.normal(scale=0.5, size=3)  # not the anchors' camera
    x, idx = padded_state(Ls, kinds, camera)
    kinds = np.array(kinds)
    got = inverse_distances(x, idx, kinds)
    pts, _ = lp.to_euclidean(kinds, np.stack(Ls))
    np.testing.assert_allclose(got, 1.0 / np.linalg.norm(pts - camera, axis=1),
                               atol=INV_DIST_TOL, rtol=0)
    # at infinity (rho = 0) and beyond (rho < 0): inverse distance 0, not NaN
    for kind, col in ((lp.IDP, 5), (lp.AHP, 6)):
        for rho in (0.0, -0.1):
            L = landmark_in_view(rng, kind, p, q)
            L[col] = rho
            x1, idx1 = padded_state([L], [kind], camera)
            assert inverse_distances(x1, idx1, np.array([kind]))[0] == 0.0


def in_view_inverse_distances(x: np.ndarray, slots: list, keep: int) -> np.ndarray:
    """Inverse distances from the camera of the first ``keep`` landmarks in ``slots`` that
    project inside the image, recomputed from public pieces (``to_euclidean``, ``observe_landmarks``)."""
    kinds = np.array([{"idp": lp.IDP, "ahp": lp.AHP, "euclidean": lp.EUCLIDEAN}[k]
                      for _, k, _ in slots[:keep]])
    L = np.zeros((keep, lp.PAD))
    for j, (_, k, o) in enumerate(slots[:keep]):
        s = lp.SIZE[kinds[j]]
        L[j, :s] = x[o:o + s]
    uv, hz, _, _ = lp.observe_landmarks(K, x[0:3], x[3:7], kinds, L, jacobians=False)
    W, H = IMAGE_SIZE
    vis = (hz > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5) \
        & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
    pts, _ = lp.to_euclidean(kinds[vis], L[vis])
    return 1.0 / np.linalg.norm(pts - x[0:3], axis=1)


@pytest.mark.parametrize("param", ["idp", "ahp"])
def test_map_depth_prior_is_the_median_of_the_landmarks_in_view(param):
    """Frame 0 (empty map): the fixed prior of min_depth_m. Later frames: mean the
    median inverse distance of the landmarks in view, std half the larger of that
    median and the nearest one's distance from it."""
    poses, pts, odo, Q, frames, _ = loop_world(4, n_points=300)
    cfg = MonoEkfConfig(min_depth_m=SCENE_MIN_DEPTH_M, depth_prior="map", landmark_param=param,
                        max_landmarks=30)
    rho_col = 5 if param == "idp" else 6
    checked = []

    def check(ekf, k):
        new = ekf.last_update["initialised"]
        if not len(new):
            return
        x, P, slots = ekf.state_vector(), ekf.state_covariance(), ekf.landmark_slots()
        keep = len(slots) - len(new)  # new landmarks are appended last
        assert [t for t, _, _ in slots[keep:]] == new.tolist()
        if keep == 0:
            rho0, sigma = cfg.rho0, cfg.sigma_rho
        else:
            inv = in_view_inverse_distances(x, slots, keep)
            rho0 = float(np.median(inv))
            sigma = 0.5 * max(rho0, float(inv.max()) - rho0)
        for _, _, o in slots[keep:]:
            assert x[o + rho_col] == pytest.approx(rho0, abs=PRIOR_TOL)
            assert np.sqrt(P[o + rho_col, o + rho_col]) == pytest.approx(sigma, abs=PRIOR_TOL)
        checked.append(keep)

    ekf = run_filter(cfg, poses[:1], odo, Q, frames[:1])
    check(ekf, 0)
    run_filter(cfg, poses[:25], odo, Q, frames[:25], frame_hook=check)
    assert checked[0] == 0 and any(c > 0 for c in checked[1:])


def test_fixed_depth_prior_is_the_default():
    """The default keeps every new landmark at the fixed prior of min_depth_m."""
    poses, pts, odo, Q, frames, _ = loop_world(4, n_points=300)
    cfg = MonoEkfConfig(min_depth_m=SCENE_MIN_DEPTH_M)
    assert cfg.depth_prior == "fixed"
    seen = []

    def check(ekf, k):
        new = ekf.last_update["initialised"]
        x, slots = ekf.state_vector(), ekf.landmark_slots()
        for _, _, o in slots[len(slots) - len(new):]:
            seen.append(x[o + 5])

    run_filter(cfg, poses[:15], odo, Q, frames[:15], frame_hook=check)
    assert seen and np.allclose(seen, cfg.rho0, atol=PRIOR_TOL, rtol=0)
