"""Imported first by every benchmark script: a stop signal while numpy, gtsam and the
toolkit load (a second or two) ends the script with one line, as :func:`entry.run`
does once the script runs, not with a KeyboardInterrupt traceback from inside an
import. Nothing has been measured or written by then, so nothing is lost.

Only in a script run as such (its file beside this one is ``__main__``): a test that
imports a script keeps pytest's own handlers.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

#: Exit status of a script a signal ended while it started: the shell's 128 + signal.
STATUS_BASE = 128


def _stop(signum, frame) -> None:
    name = Path(sys.argv[0]).name
    try:
        print(f"{name}: interrupted ({signal.Signals(signum).name}) while starting", file=sys.stderr)
    except (OSError, ValueError):
        pass
    raise SystemExit(STATUS_BASE + signum)  # no traceback, and Python's own exit


def _is_a_script_here() -> bool:
    main = sys.modules.get("__main__")
    where = getattr(main, "__file__", None)
    return where is not None and Path(where).resolve().parent == Path(__file__).resolve().parent


if _is_a_script_here():
    for _s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(_s, _stop)
