"""Filtering back ends: EKF-SLAM and FastSLAM (pure numpy; never gtsam or rerun)."""
