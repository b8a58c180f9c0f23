"""The figure every benchmark writes beside its JSON (issue 19 item 4): one helper for all.

A script describes its figure as :class:`Panel` s (line or grouped-bar charts,
with units in the axis labels and targets as dashed lines) and calls
:func:`save_figure` with the path of its JSON; the PNG gets the same name with
``.png``. Benchmarks are scripts around the library, so matplotlib is imported
here directly (the library keeps it in ``graphslam.visualisation.plots``).
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

#: Styles of the target lines, in turn (several targets on one panel stay apart).
TARGET_STYLES = (("k", "--"), ("0.4", ":"), ("tab:red", "-."))
#: Width and height of one panel (inches) and the resolution: keeps each PNG well under 150 kB.
PANEL_IN = (5.6, 3.8)
DPI = 90


@dataclass
class Panel:
    """One chart. ``series``: legend label -> (x values, y values).

    ``kind="line"`` draws each series against numeric x; ``kind="bar"`` draws
    grouped bars, x being category names (the union of all series, in order
    of appearance). ``targets``: label -> y of a dashed horizontal line;
``ylim`` zooms on a narrow range (bars of accuracies near 100 %). ``kind="map"``
draws x-y paths at equal scale, the series named in ``points`` as dots (landmarks).
    """

    title: str
    xlabel: str
    ylabel: str
    series: dict[str, tuple[Sequence, Sequence]]
    kind: str = "line"
    logx: bool = False
    logy: bool = False
    targets: dict[str, float] = field(default_factory=dict)
    ylim: tuple[float, float] | None = None
    points: tuple[str, ...] = ()


def png_beside(json_path: Path | str) -> Path:
    """The PNG written next to a benchmark's JSON."""
    return Path(json_path).with_suffix(".png")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only: no display on servers or CI
    import matplotlib.pyplot as plt

    return plt


def _ticker():
    import matplotlib.ticker

    return matplotlib.ticker


def _two_five(v: float, _pos=None) -> str:
    """Minor log ticks labelled at 2 and 5 times a power of ten only."""
    mantissa = round(v / 10 ** math.floor(math.log10(v)), 6) if v > 0 else 0
    return f"{v:g}" if mantissa in (2, 5) else ""


def _finite(v) -> float:
    return float(v) if v is not None and math.isfinite(float(v)) else math.nan


def _bars(ax, panel: Panel) -> None:
    cats: list = []
    for xs, _ in panel.series.values():
        cats += [str(c) for c in xs if str(c) not in cats]
    n = max(len(panel.series), 1)
    width = 0.8 / n
    # past the default cycle's 10 colours, 20 distinct ones: no two series look alike
    palette = _pyplot().get_cmap("tab20") if n > 10 else None
    for i, (label, (xs, ys)) in enumerate(panel.series.items()):
        pos = [cats.index(str(c)) - 0.4 + width * (i + 0.5) for c in xs]
        colour = None if palette is None else palette(i % 20)
        ax.bar(pos, [_finite(y) for y in ys], width, label=label, color=colour)
    ax.set_xticks(range(len(cats)))
    ax.set_xticklabels(cats, rotation=20 if sum(len(c) for c in cats) > 40 else 0,
                       ha="right" if sum(len(c) for c in cats) > 40 else "center", fontsize=8)


def _draw(ax, panel: Panel) -> None:
    ticker = _ticker()
    if panel.kind == "bar":
        _bars(ax, panel)
    elif panel.kind == "line":
        for label, (xs, ys) in panel.series.items():
            ax.plot([float(x) for x in xs], [_finite(y) for y in ys], marker="o", ms=3, label=label)
        if all(float(x).is_integer() for xs, _ in panel.series.values() for x in xs):
            ax.xaxis.set_major_locator(ticker.MaxNLocator(integer=True))  # seeds, frames, counts
    elif panel.kind == "map":
        for label, (xs, ys) in panel.series.items():
            if label in panel.points:
                ax.scatter([float(x) for x in xs], [_finite(y) for y in ys], s=14, label=label,
                           zorder=3)
            else:
                ax.plot([float(x) for x in xs], [_finite(y) for y in ys], lw=0.8, label=label)
        ax.set_aspect("equal", adjustable="datalim")
    else:
        raise ValueError(f"panel kind {panel.kind!r}: 'line', 'bar' or 'map'")
    for (label, y), (colour, style) in zip(panel.targets.items(), TARGET_STYLES * 4):
        ax.axhline(y, color=colour, ls=style, lw=1.2, label=label)
    for on, axis, scale, lim in ((panel.logx, ax.xaxis, ax.set_xscale, ax.get_xlim),
                                 (panel.logy, ax.yaxis, ax.set_yscale, ax.get_ylim)):
        if on:
            scale("log")
            # plain numbers (2, 30, 0.5) rather than 2 x 10^0; minor ticks labelled only
            # on ranges under about two decades (else they crowd)
            axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            lo, hi = lim()
            narrow = lo > 0 and math.log10(hi / lo) < 2.1
            axis.set_minor_formatter(ticker.FuncFormatter(_two_five) if narrow else ticker.NullFormatter())
    if panel.logy and panel.kind == "bar" and panel.ylim is None:
        low = [float(y) for _, ys in panel.series.values() for y in ys if _finite(y) > 0]
        if low:  # bars start at 0: show the shortest one whole on a log axis
            ax.set_ylim(bottom=min(low) / 2)
    if panel.ylim is not None:
        ax.set_ylim(*panel.ylim)
    ax.set_title(panel.title, fontsize=10)
    ax.set_xlabel(panel.xlabel)
    ax.set_ylabel(panel.ylabel)
    ax.grid(alpha=0.3)
    entries = len(panel.series) + len(panel.targets)
    if panel.kind == "bar" and entries > 3:  # many bars fill the panel: legend beside it
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    elif entries:
        ax.legend(fontsize=7)


def save_figure(json_path: Path | str, title: str, panels: list[Panel], ncols: int | None = None) -> Path:
    """Draw ``panels`` under ``title`` into the PNG beside ``json_path``; returns its path."""
    plt = _pyplot()
    ncols = ncols or min(len(panels), 2)
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = plt.subplots(nrows, ncols, squeeze=False, constrained_layout=True,
                             figsize=(PANEL_IN[0] * ncols, PANEL_IN[1] * nrows))
    for ax, panel in zip(axes.flat, panels):
        _draw(ax, panel)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(textwrap.fill(title, 62 * ncols), fontsize=11)  # long titles wrap, not clip
    path = png_beside(json_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    print(f"wrote {path}")
    return path
