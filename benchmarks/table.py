"""Rebuild the targets table of ``benchmarks/README.md`` from the committed results (issue 20 item 6).

Every benchmark writes a ``"summary"`` record (or a list under
``"summaries"``) made by :func:`timing.summary` into its JSON. This script
reads every ``benchmarks/figures/**/*.json`` (the results the README shows),
and replaces the text between the ``<!-- targets:begin -->`` and
``<!-- targets:end -->`` markers of ``benchmarks/README.md`` with one row per
summary: ours, the floor (in words and its value), the ratio, the team's
target, whether it is met, and the command that made the figure. Results
without a summary are listed after the table, so none is silently left out.

    python benchmarks/table.py [--check]

``--check`` exits 1 if the README's table is not what the results give
(stale), without writing.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"
README = HERE / "README.md"
BEGIN, END = "<!-- targets:begin -->", "<!-- targets:end -->"


def summaries(figures: Path = FIGURES) -> tuple[list[tuple[str, dict]], list[str]]:
    """(figure path without .json, relative to ``figures``, summary) for every summary found,
    and the paths without one."""
    rows, missing = [], []
    for path in sorted(figures.rglob("*.json")):
        data = json.loads(path.read_text())
        if not isinstance(data, dict):     # an older result written as a bare list
            data = {}
        found = data.get("summaries") or ([data["summary"]] if "summary" in data else [])
        stem = path.relative_to(figures).with_suffix("").as_posix()
        if not found:
            missing.append(stem)
        rows.extend((stem, s) for s in found)
    return rows, missing


def _value(v: float, unit: str) -> str:
    if unit.startswith("s"):
        rest = unit[1:]
        return f"{1e3 * v:.3g} ms{rest}" if v < 1 else f"{v:.3g} s{rest}"
    return f"{v:.3g} {unit}"


def render(rows: list[tuple[str, dict]], missing: list[str]) -> str:
    """The markdown between the markers."""
    lines = ["| benchmark | ours | floor | floor value | ratio | target | met | command |",
             "|---|---|---|---|---|---|---|---|"]
    for stem, s in rows:
        met = {True: "yes", False: "**no**", None: "-"}[s.get("meets_target")]
        target = "-" if s.get("target") is None else f"{s['target']:g}"
        if s.get("target") is None and s.get("target_ms") is not None:  # an absolute target
            met = {True: "yes", False: "**no**", None: "-"}[s.get("meets_target_ms")]
            target = f"<= {s['target_ms']:g} ms"
        lines.append(f"| {s['name']} ([{stem}](figures/{stem}.png)) | {_value(s['ours'], s['unit'])} "
                     f"| {s['floor']} | {_value(s['floor_value'], s['unit'])} | {s['ratio']:.2f} "
                     f"| {target} | {met} | `{s['command']}` |")
    text = "\n".join(lines)
    if missing:
        text += ("\n\nResults without a floor/target summary (they score accuracy or "
                 "report a measurement, see their sections): " + ", ".join(missing) + ".")
    return text + "\n"


def update(readme: Path = README, figures: Path = FIGURES, check: bool = False) -> bool:
    """Write the table into ``readme``; returns whether it was already current."""
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{readme}: markers {BEGIN} / {END} not found")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = head + BEGIN + "\n" + render(*summaries(figures)) + END + tail
    if new == text:
        return True
    if not check:
        readme.write_text(new)
    return False


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the table is stale; write nothing")
    args = ap.parse_args(argv)
    current = update(check=args.check)
    print("table current" if current else ("table stale" if args.check else f"wrote {README}"))
    return 1 if (args.check and not current) else 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
