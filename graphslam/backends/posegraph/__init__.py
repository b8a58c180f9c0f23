"""Pose-graph optimisation (2-D and 3-D) on GTSAM: iSAM2 and batch, initialisers."""
