"""slamcore.spatial.geometry against gtsam where they compute the same thing."""

from __future__ import annotations

import gtsam
import numpy as np

from slamcore.spatial.geometry import se3_adjoint, se3_exp

#: Rounding of a 6x6 product of unit-scale matrices.
EXACT = 1e-12


def test_adjoint_is_gtsams_with_the_blocks_of_rho_phi():
    rng = np.random.default_rng(7)
    swap = np.r_[3:6, 0:3]  # gtsam's [phi, rho] -> our [rho, phi]
    for _ in range(20):
        T = se3_exp(rng.normal(size=6))
        ours = se3_adjoint(T)
        theirs = gtsam.Pose3(T).AdjointMap()[np.ix_(swap, swap)]
        assert np.max(np.abs(ours - theirs)) < EXACT
        xi = rng.normal(scale=0.1, size=6)
        # T exp(xi) = exp(Ad_T xi) T
        assert np.max(np.abs(T @ se3_exp(xi) - se3_exp(ours @ xi) @ T)) < 1e-9
