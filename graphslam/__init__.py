"""graphslam: graph-SLAM toolkit on GTSAM.

Import the parts you need; nothing heavy happens at import time:

- :mod:`slamcore.planar.records` and :mod:`slamcore.planar.backend`: numpy records and the
  back-end contract (no gtsam);
- :mod:`graphslam.backends.planar.isam2`: the iSAM2 back end;
- :mod:`graphslam.sources`: synthetic world and dataset readers;
- :mod:`graphslam.pipelines.planar`, :mod:`graphslam.cli.main`: the application.
"""

__version__ = "0.1.0"
