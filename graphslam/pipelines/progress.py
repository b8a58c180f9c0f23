"""Progress on stderr: a tqdm bar on a terminal, a plain line every few seconds elsewhere.

tqdm switches itself off when stderr is not a terminal (``disable=None``), so a
long run logged to a file, or under CI, printed nothing for minutes; and a bar
forced on writes carriage returns a log shows as one endless line. Off a
terminal :class:`ProgressLines` prints one line every
:data:`PROGRESS_LINE_INTERVAL_S` seconds (count, share, rate, time left, the
postfix) and, if it printed any, a last one at the end; it has the part of tqdm's interface the
pipelines use (iteration, ``update``, ``set_postfix``, ``close``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Sized

__all__ = ["progress", "ProgressLines", "PROGRESS_LINE_INTERVAL_S", "SolveProgress"]

#: Seconds between two progress lines off a terminal: a log stays short (six lines a
#: minute) and a stalled run still shows within seconds that it lives.
PROGRESS_LINE_INTERVAL_S = 10.0


class ProgressLines:
    """tqdm's interface as plain lines (module docstring)."""

    def __init__(
        self,
        iterable: Iterable | None = None,
        total: int | None = None,
        desc: str = "",
        unit: str = "it",
        file=None,
        interval_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.iterable = iterable
        if total is None and isinstance(iterable, Sized):
            total = len(iterable)
        self.total, self.desc, self.unit = total, desc, unit
        self.file = file if file is not None else sys.stderr
        self.interval_s = PROGRESS_LINE_INTERVAL_S if interval_s is None else interval_s
        self.clock = clock
        self.n = 0
        self._start = self._last = clock()
        self._printed_n = 0
        self._postfix: dict = {}
        self._closed = False

    def __iter__(self):
        if self.iterable is None:
            raise TypeError("Progress made without an iterable cannot be iterated; call update()")
        for item in self.iterable:
            yield item
            self.update(1)

    def update(self, n: int = 1) -> None:
        self.n += n
        now = self.clock()
        if now - self._last >= self.interval_s:
            self._line(now)

    def set_postfix(self, refresh: bool = False, **values) -> None:
        self._postfix = values

    def close(self) -> None:
        # a last line only after earlier ones: work shorter than one interval stays quiet
        if not self._closed and 0 < self._printed_n < self.n:
            self._line(self.clock(), final=True)
        self._closed = True

    def _line(self, now: float, final: bool = False) -> None:
        elapsed = max(now - self._start, 1e-9)
        rate = self.n / elapsed
        head = f"{self.desc}: {self.n}" + (f"/{self.total}" if self.total else "")
        parts = [f"{head} {self.unit}"]
        if self.total:
            parts[0] += f" ({100 * self.n / self.total:.0f} %)"
        parts.append(f"{rate:.3g} {self.unit}/s")
        if final:
            parts.append(f"{elapsed:.0f} s")
        elif self.total and rate > 0:
            parts.append(f"about {_duration((self.total - self.n) / rate)} left")
        if self._postfix:
            parts.append(", ".join(f"{k}={v}" for k, v in self._postfix.items()))
        try:
            print("; ".join(parts), file=self.file, flush=True)
        except (OSError, ValueError):
            pass  # a closed or full stderr costs the progress line, never the run
        self._last, self._printed_n = now, self.n


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def progress(
    iterable: Iterable | None = None,
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool = True,
    file=None,
):
    """A progress object with tqdm's interface: a tqdm bar when ``file`` (default stderr)
    is a terminal, :class:`ProgressLines` when it is not, a silent tqdm when not
    ``enabled``."""
    from tqdm import tqdm

    file = file if file is not None else sys.stderr
    if not enabled:
        return tqdm(iterable, total=total, disable=True)
    try:
        terminal = file.isatty()
    except (AttributeError, ValueError):
        terminal = False
    if terminal:
        return tqdm(iterable, total=total, desc=desc, unit=unit, file=file, dynamic_ncols=True)
    return ProgressLines(iterable, total=total, desc=desc, unit=unit, file=file)


#: What each stop-check point of a pose-graph solve is doing, and what its count counts
#: (:data:`graphslam.backends.posegraph.solver.StopCheck`'s points; ``init`` and
#: ``certificate`` are waits without a count).
SOLVE_PHASES = {
    "step": ("iSAM2", "update"),
    "lm": ("batch LM", "iteration"),
    "gnc": ("GNC", "iteration"),
    "init": ("Shonan averaging", None),
    "certificate": ("certificate", None),
}


class SolveProgress:
    """Progress of a pose-graph solve on stderr, from its stop checks: ``tracker(point,
    step)``. A whole-graph solve has phases (iSAM2 updates, LM and GNC iterations, Shonan
    averaging, the certificate) and no total known in advance, so no bar: the phase, its
    count and the time so far, rewritten in place on a terminal (five times a second at
    most) and as a line every :data:`PROGRESS_LINE_INTERVAL_S` elsewhere. NewCollege's
    default run went 40 s and more without a word."""

    def __init__(self, enabled: bool = True, file=None, clock: Callable[[], float] = time.monotonic) -> None:
        self.file = file if file is not None else sys.stderr
        self.enabled = enabled
        self.clock = clock
        try:
            self.terminal = bool(self.file.isatty())
        except (AttributeError, ValueError):
            self.terminal = False
        self._start = self._last = clock()
        self._width = 0  # of the line drawn in place

    def __call__(self, point: str, step: int = 0) -> None:
        if not self.enabled:
            return
        now = self.clock()
        if now - self._last < (0.2 if self.terminal else PROGRESS_LINE_INTERVAL_S):
            return
        phase, unit = SOLVE_PHASES.get(point, (point, None))
        count = f" {unit} {step}" if unit is not None else ""
        self._write(f"solving: {phase}{count}, {now - self._start:.0f} s")
        self._last = now

    def close(self) -> None:
        """Clear the line drawn in place (a terminal); lines written elsewhere stay."""
        if self._width:
            self._write("", clear=True)

    def _write(self, text: str, clear: bool = False) -> None:
        try:
            if self.terminal:
                self.file.write("\r" + text.ljust(self._width) + ("\r" if clear else ""))
                self._width = 0 if clear else len(text)
            else:
                print(text, file=self.file)
            self.file.flush()
        except (OSError, ValueError):
            pass  # a closed or full stderr costs the progress line, never the run
