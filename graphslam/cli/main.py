"""``graphslam`` command line: parses, calls the library, prints.

Any :class:`~slamcore.errors.GraphSlamError` becomes one line on stderr and
exit status 2; Ctrl-C writes what was estimated so far and exits with 130.
"""

from __future__ import annotations

import argparse
import sys

from graphslam.cli.common import EXIT_ERROR, EXIT_INTERRUPTED
from slamcore.errors import GraphSlamError


def build_parser() -> argparse.ArgumentParser:
    """The ``graphslam`` parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="graphslam",
        description="Graph-SLAM toolkit on GTSAM: run SLAM on a sequence and get a trajectory, "
                    "a map, metrics and a Rerun recording.")
    from graphslam import __version__

    parser.add_argument("--version", action="version", version=f"graphslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    from graphslam.cli import compare, localize, loops, vocab
    from graphslam.cli.run import command as run

    for command in (run, compare, vocab, loops, localize):
        command.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except GraphSlamError as e:
        print(f"graphslam: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("graphslam: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
