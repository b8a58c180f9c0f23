"""Every config section the tree defines is one a config file may hold, and a file
with an unknown section or key is refused by the commands with file and line."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from graphslam.registry import CONFIG_SECTIONS
from tests.conftest import ROOT
from tests.layering import module_files


def _sections_in_tree() -> set[str]:
    found = set()
    for path in module_files(ROOT).values():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and node.target.id == "SECTION" and isinstance(node.value, ast.Constant)):
                found.add(node.value.value)
    return found


def test_registry_lists_every_section_of_the_tree():
    assert set(CONFIG_SECTIONS) == _sections_in_tree()
    assert len(CONFIG_SECTIONS) == len(set(CONFIG_SECTIONS))


@pytest.mark.parametrize("text, line, words", [
    ("[isam2]\npolish = false\n\n[mono-ekf]\nmax_landmarks = 3\n", 4, "unknown section [mono-ekf]"),
    ("[synthetic]\nseed = 1\nsensr_range_m = 3\n", 3, "unknown key(s) ['sensr_range_m']"),
    ("[synthetic]\nsigma_r_m = -1\n", 2, "synthetic.sigma_r_m"),
    ("synthetic = 5\n", 1, "must be a table"),
])
def test_run_refuses_bad_config_with_file_and_line(tmp_path, text, line, words):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "graphslam.cli.main", "run", "--config", str(cfg),
                           "--rerun", "off", "--quiet", "--max-steps", "5", "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{cfg}:{line}:" in err and words in err, err


def test_absurd_particle_count_is_one_line_with_file_and_line(tmp_path, capsys):
    """1e11 particles would need terabytes (filters.fastslam.MAX_PARTICLES): refused
    before anything is allocated, as one line naming the file and line, exit 2."""
    from graphslam.cli.main import main

    cfg = tmp_path / "particles.toml"
    cfg.write_text("[fastslam]\nseed = 1\nn_particles = 1e11\n")
    out = tmp_path / "out"
    rc = main(["run", "--backend", "fastslam1", "--config", str(cfg), "--rerun", "off",
               "--quiet", "--max-steps", "5", "--out", str(out)])
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"graphslam: error: {cfg}:3: fastslam.n_particles must be"), err
    assert not out.exists()


#: The field metadata of :func:`slamcore.config.bounded`.
RANGE_KEYS = {"min", "max", "gt", "lt"}


def _config_classes() -> list[type]:
    """Every dataclass of the library that a config file or ``bounded`` fields make a
    config: it has a ``SECTION`` or ``TABLE``, or a field with range metadata."""
    import dataclasses
    import importlib

    found = []
    for name in module_files(ROOT):
        module = importlib.import_module(name)
        for cls in vars(module).values():
            if (isinstance(cls, type) and cls.__module__ == name and dataclasses.is_dataclass(cls)
                    and ("SECTION" in vars(cls) or "TABLE" in vars(cls)
                         or any(RANGE_KEYS & set(f.metadata) for f in dataclasses.fields(cls)))):
                found.append(cls)
    return found


def test_every_config_is_checked_when_built():
    """A config built in code is held to the file's rules only if it validates itself:
    the base class makes that structural (a new config cannot forget it)."""
    from slamcore.config import Validated

    classes = _config_classes()
    assert len(classes) >= 20
    assert [c.__qualname__ for c in classes if not issubclass(c, Validated)] == []


def test_every_gate_names_fields_of_its_config():
    """A gate naming a field that was renamed would silently never say anything."""
    import dataclasses

    gated = [c for c in _config_classes() if getattr(c, "GATES", ())]
    assert len(gated) >= 7
    for cls in gated:
        names = {f.name for f in dataclasses.fields(cls)}
        for gate in cls.GATES:
            assert set(gate.fields) <= names, (cls.__qualname__, gate.fields)
            cls().inert_settings()  # every condition evaluates on the defaults
