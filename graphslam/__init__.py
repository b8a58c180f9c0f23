"""graphslam: graph-SLAM toolkit on GTSAM.

Import the parts you need; nothing heavy happens at import time:

- :mod:`graphslam.types` and :mod:`graphslam.backend`: numpy records and the
  back-end contract (no gtsam);
- :mod:`graphslam.isam2`: the iSAM2 back end;
- :mod:`graphslam.sources`: synthetic world and dataset readers;
- :mod:`graphslam.pipeline`, :mod:`graphslam.cli`: the application.
"""

__version__ = "0.1.0"
