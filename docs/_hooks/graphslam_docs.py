"""MkDocs hook: pages show what the code says, generated at build time.

Two markers, each alone on a line of a page:

- ``<!-- graphslam-help: run -->``: the ``--help`` of that sub-command (``graphslam``
  alone for the top level), from the same argparse parser the command uses, so a
  page cannot list an option the command lacks;
- ``<!-- graphslam-config: isam2 ekf -->``: one table per config section (key,
  default, allowed values or bounds, and the description from the class's
  ``Attributes:`` docstring), from the frozen dataclasses ``--config`` fills;
- ``<!-- graphslam-docstring: graphslam.sources.ground_truth -->``: a module's
  docstring (where the readers state the formats they accept), reST roles and
  literals turned into Markdown.

A marker naming an unknown command or section fails the build (``--strict`` or not).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import io
import os
import re
from contextlib import redirect_stdout
from pathlib import Path

HELP = re.compile(r"^<!-- graphslam-help: ([\w-]+) -->$", re.M)
CONFIG = re.compile(r"^<!-- graphslam-config: ([\w .-]+) -->$", re.M)
DOCSTRING = re.compile(r"^<!-- graphslam-docstring: ([\w.]+) -->$", re.M)
ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("slamcore", "graphslam", "frontend", "loopclosure", "filters")


def on_page_markdown(markdown, page, config, files):  # noqa: ARG001 (MkDocs' signature)
    markdown = HELP.sub(lambda m: help_block(m.group(1)), markdown)
    markdown = DOCSTRING.sub(lambda m: module_doc(m.group(1)), markdown)
    return CONFIG.sub(lambda m: config_tables(m.group(1).split()), markdown)


def help_block(command: str) -> str:
    from graphslam.cli.main import build_parser

    argv = ["--help"] if command == "graphslam" else [*command.split("-"), "--help"]
    text = io.StringIO()
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "92"  # argparse wraps to the terminal; pages want one width
    try:
        with redirect_stdout(text):
            build_parser().parse_args(argv)
    except SystemExit as exit_:
        if exit_.code not in (0, None):
            raise ValueError(f"graphslam-help: no command {command!r}") from None
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns
    return "```text\n" + text.getvalue().rstrip() + "\n```"


@functools.cache  # nine markers ask; the tree is scanned and imported once a build
def config_classes() -> dict[str, type]:
    """Section name -> the frozen dataclass that reads it, for every ``SECTION`` in the tree."""
    found: dict[str, type] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "SECTION" not in path.read_text(encoding="utf-8"):
                continue
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            for _, cls in inspect.getmembers(importlib.import_module(module), inspect.isclass):
                section = cls.__dict__.get("SECTION")
                if dataclasses.is_dataclass(cls) and isinstance(section, str):
                    found[section] = cls
    return found


def attribute_docs(cls: type) -> dict[str, str]:
    """``name -> description`` from a Google-style ``Attributes:`` docstring block
    (``a, b: text`` documents both)."""
    doc = inspect.getdoc(cls) or ""
    block = re.search(r"^Attributes:\n((?:[ \t]+.*\n?|\n)*)", doc, re.M)
    docs: dict[str, str] = {}
    if not block:
        return docs
    names: list[str] = []
    for line in block.group(1).splitlines():
        entry = re.match(r"^ {4}([\w, ]+):\s*(.*)$", line)
        if entry and not line.startswith(" " * 5):
            names = [n.strip() for n in entry.group(1).split(",")]
            for n in names:
                docs[n] = entry.group(2).strip()
        elif line.strip() and names:
            for n in names:
                docs[n] += " " + line.strip()
    return docs


def _default(value) -> str:
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if value is None:
        return "unset"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, tuple):
        return "`[" + ", ".join(repr(v) for v in value) + "]`"
    return f"`{value!r}`"


def _bounds(cls: type, field: dataclasses.Field) -> str:
    from slamcore.config import choices_of

    choices = choices_of(cls, field.name)
    if choices:
        return ", ".join(_default(c) for c in choices)
    meta = field.metadata
    parts = [f"{op} {meta[key]}" for key, op in (("min", ">="), ("gt", ">"), ("max", "<="),
                                                  ("lt", "<")) if key in meta]
    return ", ".join(parts)


def section_table(section: str, cls: type, instance=None) -> str:
    """The table of one section; a nested table shows the defaults its parent gives it."""
    nested_in = instance is not None
    instance = cls() if instance is None else instance
    docs = attribute_docs(cls)
    intro = (f"A table inside `[{section.rsplit('.', 1)[0]}]`, with the defaults it sets there."
             if nested_in else rst_to_markdown((inspect.getdoc(cls) or "").split("\n\n")[0]))
    rows = [f"### `[{section}]`", "", intro, "",
            "| key | default | allowed | what it does |", "|---|---|---|---|"]
    nested = []
    for field in dataclasses.fields(cls):
        value = getattr(instance, field.name)
        if dataclasses.is_dataclass(value):
            nested.append((f"{section}.{field.name}", value))
            continue
        text = rst_to_markdown(docs.get(field.name, "")).replace("|", "\\|")
        rows.append(f"| `{field.name}` | {_default(value)} | {_bounds(cls, field)} | {text} |")
    out = "\n".join(rows) + "\n"
    for name, value in nested:
        out += "\n" + section_table(name, type(value), value)
    return out


def config_tables(sections: list[str]) -> str:
    classes = config_classes()
    unknown = [s for s in sections if s not in classes]
    if unknown:
        raise ValueError(f"graphslam-config: no section {unknown}")
    return "\n".join(section_table(s, classes[s]) for s in sections)


def rst_to_markdown(text: str) -> str:
    """The reST the docstrings use, as Markdown: ``literals``, :role:`targets`,
    underlined titles and simple tables (kept as fixed-width text)."""
    def role(match: re.Match) -> str:  # :role:`~a.b.C` -> `C`, :role:`text <target>` -> `text`
        body = match.group(1)
        titled = re.fullmatch(r"(.*?)\s*<[^>]*>", body)
        if titled:
            return f"`{titled.group(1)}`"
        return f"`{body[1:].rsplit('.', 1)[-1]}`" if body.startswith("~") else f"`{body}`"

    text = re.sub(r":\w+:`([^`]+)`", role, text)
    text = text.replace("``", "`")
    out: list[str] = []
    lines = text.splitlines()
    in_table = False
    for i, line in enumerate(lines):
        rule = re.fullmatch(r"=+(\s+=+)+", line.strip())
        if rule:  # opens a table; the rule before a blank line (or the end) closes it
            if not in_table:
                out.append("```text")
                in_table = True
            elif i + 1 == len(lines) or not lines[i + 1].strip():
                out.append("```")
                in_table = False
            continue
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if not in_table and line.strip() and re.fullmatch(r"-{3,}|={3,}", nxt.strip()):
            out.append(f"#### {line.strip()}")
            continue
        if not in_table and re.fullmatch(r"-{3,}|={3,}", line.strip()):
            continue
        out.append(line.replace("`", "") if in_table else line)
    return "\n".join(out)


def module_doc(module: str) -> str:
    doc = importlib.import_module(module).__doc__
    if not doc:
        raise ValueError(f"graphslam-docstring: {module} has no docstring")
    return rst_to_markdown(inspect.cleandoc(doc))
