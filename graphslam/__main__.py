"""``python -m graphslam``: the same command as the ``graphslam`` console script."""

import sys

from graphslam.cli.main import main

if __name__ == "__main__":  # not when multiprocessing re-imports the main module
    sys.exit(main())
