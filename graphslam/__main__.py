"""``python -m graphslam``: the same command as the ``graphslam`` console script."""

from graphslam.cli.main import entry

if __name__ == "__main__":  # not when multiprocessing re-imports the main module
    entry()
