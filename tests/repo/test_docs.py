"""The documentation site builds cleanly and says what the code does.

The site (``docs/``, ``mkdocs.yml``) is built with ``--strict``, so a broken link,
anchor or nav entry fails the suite and with it CI. The checks below tie the
pages to the code: every command shown parses with the command's own parser,
every sub-command, back end and config section has its place, and every config
key has a description for the generated reference.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

sys.path.insert(0, str(ROOT / "docs" / "_hooks"))
import graphslam_docs  # noqa: E402  (the build hook, importable from its folder only)

PAGES = sorted((ROOT / "docs").rglob("*.md"))


def bash_commands(path: Path) -> list[str]:
    """Every ``graphslam ...`` line of the ``bash`` blocks of a page, comments dropped."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S):
        for line in block.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line.startswith("graphslam "):
                commands.append(line)
    return commands


def test_site_builds_strict(tmp_path):
    mkdocs = Path(sys.executable).with_name("mkdocs")
    result = subprocess.run(
        [str(mkdocs), "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    assert "WARNING" not in result.stderr, result.stderr[-3000:]
    site = tmp_path / "site"
    # the generated parts are there: a command's help, a config table, a reader's formats
    assert "--odometry-noise" in (site / "commands" / "run" / "index.html").read_text()
    assert "relinearize_threshold" in (site / "configuration" / "index.html").read_text()
    assert "VERTEX_SE3:QUAT" in (site / "data" / "formats" / "index.html").read_text()
    assert (site / "figures" / "camera_alone.png").is_file()


def test_every_command_shown_parses():
    from graphslam.cli.main import build_parser

    shown = [(p, c) for p in [ROOT / "README.md", *PAGES] for c in bash_commands(p)]
    assert len(shown) > 40
    bad = []
    for page, command in shown:
        try:
            build_parser().parse_args(shlex.split(command)[1:])
        except SystemExit:
            bad.append(f"{page.relative_to(ROOT)}: {command}")
    assert bad == []


def test_every_repository_file_a_command_names_is_shipped():
    named = set()
    for page in [ROOT / "README.md", *PAGES]:
        for command in bash_commands(page):
            named |= {w for w in shlex.split(command)
                      if re.fullmatch(r"benchmarks/[\w./-]+\.(?:toml|ya?ml)", w)}
    assert named
    assert sorted(n for n in named if not (ROOT / n).is_file()) == []


def test_every_subcommand_has_a_page_with_its_help():
    from graphslam.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    markers = {m for p in PAGES
               for m in re.findall(r"<!-- graphslam-help: ([\w-]+) -->", p.read_text())}
    missing = [c for c in sub.choices
               if c not in markers and not any(m.startswith(c + "-") for m in markers)]
    assert missing == []


def test_every_back_end_is_on_the_overview():
    from graphslam import registry
    from graphslam.backend_table import VISUAL_COMPARE_BACKENDS

    page = (ROOT / "docs" / "backends" / "index.md").read_text()
    names = {*registry.BACKENDS, *registry.POSEGRAPH_BACKENDS, *registry.VISUAL_BACKENDS,
             *VISUAL_COMPARE_BACKENDS}
    assert sorted(n for n in names if f"`{n}`" not in page) == []


def test_every_config_section_is_in_the_reference_and_every_key_described():
    from graphslam import registry

    text = "".join(p.read_text() for p in PAGES)
    listed = {s for m in re.findall(r"<!-- graphslam-config: ([\w .-]+) -->", text)
              for s in m.split()}
    assert sorted(set(registry.CONFIG_SECTIONS) - listed) == []
    undocumented = [f"[{section}] {f.name}"
                    for section, cls in graphslam_docs.config_classes().items()
                    for f in dataclasses.fields(cls)
                    if f.name not in graphslam_docs.attribute_docs(cls)]
    assert undocumented == []


@pytest.mark.parametrize("text, expected", [
    (":class:`~slamcore.planar.records.Observation` and ``x``", "`Observation` and `x`"),
    (":func:`read_kitti`", "`read_kitti`"),
    ("Title\n-----\nbody", "#### Title\nbody"),
    ("a\n\n===  ===\nx    ``y``\n===  ===\n\nb", "a\n\n```text\nx    y\n```\n\nb"),
])
def test_rst_to_markdown(text, expected):
    assert graphslam_docs.rst_to_markdown(text) == expected


def test_a_marker_naming_nothing_fails_the_build():
    with pytest.raises(ValueError, match="no command"):
        graphslam_docs.help_block("no-such-command")
    with pytest.raises(ValueError, match="no section"):
        graphslam_docs.config_tables(["no_such_section"])
