"""Configuration loading and checking (slamcore.config), on toy config classes."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

import pytest

from slamcore.config import ConfigFile, Gate, Validated, bounded, choices_of, from_dict, load_section
from slamcore.errors import ConfigError


@dataclass(frozen=True)
class Inner(Validated):
    SECTION: ClassVar[str] = "inner"
    n_features: int = bounded(100, min=1)


#: A nested default that differs from Inner's own defaults.
SPECIAL_INNER = Inner(42)


@dataclass(frozen=True)
class Outer(Validated):
    SECTION: ClassVar[str] = "outer"
    mode: Literal["fast", "exact"] = "fast"
    sigma_m: float = bounded(0.1, gt=0.0)
    probability: float = bounded(0.99, gt=0.0, lt=1.0)
    count: int = bounded(3, min=0)
    name: str | None = None
    inner: Inner = field(default_factory=Inner)
    special: Inner = SPECIAL_INNER


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_defaults_file_and_overrides_in_that_order(tmp_path):
    p = _write(tmp_path, "c.toml", "[outer]\ncount = 7\nsigma_m = 2\n[outer.inner]\nn_features = 5\n")
    cfg = load_section(Outer, p, {"count": 9, "mode": None})
    assert cfg == Outer(mode="fast", sigma_m=2.0, count=9, inner=Inner(5))
    assert isinstance(cfg.sigma_m, float)  # an integer in the file becomes the field's float


def test_file_is_parsed_once_and_sections_come_from_it(tmp_path):
    p = _write(tmp_path, "c.toml", "[outer]\ncount = 1\n")
    config = ConfigFile.read(p)
    p.unlink()  # nothing reads the file again
    assert config.section(Outer).count == 1 and config.section(Inner) == Inner()


@pytest.mark.parametrize("name, text, line, words", [
    ("c.toml", "[outer]\ncount = 1\n\n[outr]\nx = 1\n", 4, "unknown section [outr]"),
    ("c.toml", "[outer]\ncount = 1\ncuont = 2\n", 3, "unknown key(s) ['cuont']"),
    ("c.toml", "[outer]\n[outer.inner]\nn_feature = 2\n", 3, "unknown key(s) ['n_feature']"),
    ("c.toml", "[outer]\nmode = \"slow\"\n", 2, "outer.mode must be one of ['fast', 'exact']"),
    ("c.toml", "[outer]\ncount = -1\n", 2, "outer.count must be >= 0"),
    ("c.toml", "[outer]\nprobability = 1.0\n", 2, "outer.probability must be > 0.0 and < 1.0"),
    ("c.toml", "[outer]\ncount = 1.5\n", 2, "expected an integer"),
    ("c.toml", "[outer]\ncount = 100000000000000000000\n", 2, "beyond what this machine"),
    ("c.toml", "[outer]\nsigma_m = \"big\"\n", 2, "expected a number"),
    ("c.toml", "[outer]\ncount = \n", 2, ""),  # TOML syntax error keeps its line
    ("c.toml", "outer = 3\n", 1, "[outer] must be a table"),
    ("c.yaml", "outer:\n  count: 1\n  cuont: 2\n", 3, "unknown key(s) ['cuont']"),
    ("c.yaml", "outer:\n  mode: slow\n", 2, "must be one of"),
    ("c.yaml", "outer: [1, 2\n", 2, ""),
])
def test_bad_files_name_file_and_line(tmp_path, name, text, line, words):
    p = _write(tmp_path, name, text)
    with pytest.raises(ConfigError) as e:
        config = ConfigFile.read(p)
        config.check_sections(["outer", "inner"])
        config.section(Outer)
    assert e.value.path == str(p) and e.value.line == line, str(e.value)
    assert words in str(e.value)
    assert "\n" not in str(e.value)


def test_byte_order_mark_is_not_part_of_the_first_section(tmp_path):
    p = tmp_path / "bom.toml"
    p.write_bytes("\ufeff[outer]\ncount = 4\n".encode("utf-8"))
    config = ConfigFile.read(p)
    config.check_sections(["outer"])
    assert config.section(Outer).count == 4


def test_code_built_configs_are_checked_the_same_way():
    with pytest.raises(ConfigError, match="outer.mode must be one of"):
        Outer(mode="slow")
    with pytest.raises(ConfigError, match="inner.n_features must be >= 1"):
        Inner(0)
    with pytest.raises(ConfigError, match="expected true/false|expected a number"):
        Outer(count=True)
    assert choices_of(Outer, "mode") == ("fast", "exact")
    assert from_dict(Outer, {"count": 2}).count == 2
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(Outer, {"bogus": 2})


def test_missing_file_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        ConfigFile.read(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="must be .toml, .yaml or .yml"):
        ConfigFile.read(_write(tmp_path, "c.ini", "[outer]\n"))


@dataclass(frozen=True)
class Wide(Validated):
    SECTION: ClassVar[str] = "wide"
    n_features: int = bounded(100, min=1)
    cell_px: int = bounded(32, min=0)


@dataclass(frozen=True)
class Holder(Validated):
    SECTION: ClassVar[str] = "holder"
    wide: Wide = Wide(n_features=1000, cell_px=0)


def test_a_partial_nested_table_keeps_the_fields_own_default(tmp_path):
    p = _write(tmp_path, "c.toml", "[holder.wide]\nn_features = 500\n")
    assert load_section(Holder, p).wide == Wide(n_features=500, cell_px=0)
    assert load_section(Holder, None).wide == Wide(n_features=1000, cell_px=0)


# --------------------------------------------------------------------------- gates


@dataclass(frozen=True)
class Gated(Validated):
    SECTION: ClassVar[str] = "gated"
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(("polish_iterations",), "polish = true", lambda c: c.polish),
        Gate(("kernel_k", "inner"), 'kernel other than "none"', lambda c: c.kernel != "none"),
    )
    polish: bool = True
    polish_iterations: int = bounded(10, min=1)
    kernel: Literal["none", "huber"] = "none"
    kernel_k: float = bounded(1.0, gt=0.0)
    inner: Inner = field(default_factory=Inner)


def test_gated_settings_the_file_sets_are_said_with_their_line(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[gated]\npolish = false\npolish_iterations = 3\nkernel_k = 2.0\n[gated.inner]\nn_features = 7\n")
    config = ConfigFile.read(path)
    config.section(Gated)
    lines = config.inert_lines()
    assert lines == [
        f"--config {path} line 3: [gated] polish_iterations did nothing: it acts only with polish = true",
        f'--config {path} line 4: [gated] kernel_k, inner did nothing: they act only with kernel other than "none"',
    ]


def test_gates_judge_the_settings_after_the_flags(tmp_path):
    """A flag may switch a mode on or off: the gate reads the built config."""
    path = tmp_path / "c.toml"
    path.write_text("[gated]\npolish_iterations = 3\n")
    config = ConfigFile.read(path)
    config.section(Gated)
    assert config.inert_lines() == []
    config.section(Gated, {"polish": False})
    assert len(config.inert_lines()) == 1


def test_defaults_and_flags_alone_are_never_said(tmp_path):
    """Only the file's keys: a default, or a value a command sets itself, is no user's."""
    config = ConfigFile.read(None)
    config.section(Gated, {"polish": False, "polish_iterations": 4})
    assert config.inert_lines() == []
    assert Gated(polish=False).inert_settings() == {
        "polish_iterations": "polish = true",
        "kernel_k": 'kernel other than "none"',
        "inner": 'kernel other than "none"',
    }


def test_marked_sections_are_said_for_the_keys_the_file_has(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[inner]\nn_features = 5\n")
    config = ConfigFile.read(path)
    config.mark_inert("inner", None, "detector = 1")
    config.mark_inert("absent", None, "never")
    config.mark_inert("inner", ["other"], "never")
    assert config.inert_lines() == [
        f"--config {path} line 2: [inner] n_features did nothing: it acts only with detector = 1"
    ]


def test_a_flag_that_turned_the_mode_off_is_named(tmp_path):
    """``--no-polish`` under ``polish = true``: the line said "acts only with polish =
    true" beside a file that says so (thirteenth hostile pass)."""
    path = tmp_path / "c.toml"
    path.write_text("[gated]\npolish = true\npolish_iterations = 3\n")
    config = ConfigFile.read(path)
    config.section(Gated, {"polish": False})
    assert config.inert_lines() == [
        f"--config {path} line 2: [gated] polish did nothing: the command line's false, which replaced it",
        f"--config {path} line 3: [gated] polish_iterations did nothing: it acts only with polish = true "
        "(a command-line option set it otherwise)",
    ]


def test_a_file_value_the_command_line_replaced_is_said(tmp_path):
    """``--robot 2`` under ``[mrclam] all_robots = true`` ran all five robots, silent, and
    ``robot_model = "odometry"`` under ``--odometry none`` was replaced, silent
    (thirteenth hostile pass; the first is now refused by the reader's override)."""
    path = tmp_path / "c.toml"
    path.write_text('[gated]\npolish = true\nkernel = "none"\n')
    config = ConfigFile.read(path)
    config.section(Gated, {"polish": False, "kernel": "none"})
    assert config.inert_lines() == [
        f"--config {path} line 2: [gated] polish did nothing: the command line's false, which replaced it"
    ]


def test_an_integer_past_the_largest_float_is_one_error(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[outer]\nsigma_m = 1" + "0" * 400 + "\n")
    with pytest.raises(ConfigError, match="finite number"):
        load_section(Outer, path)


def test_quoted_keys_and_inline_tables_have_their_lines(tmp_path):
    """``'min_depth_m' = 0.3`` and ``mono_ekf = {min_depth_m = 0.3}`` had no line: errors
    lost it, and a check for the key by its line missed the setting (thirteenth pass)."""
    path = tmp_path / "c.toml"
    path.write_text("[outer]\n'sigma_m' = -1\n")
    with pytest.raises(ConfigError) as e:
        load_section(Outer, path)
    assert e.value.line == 2
    path.write_text('outer = {mode = "fast", count = -1}\n')
    with pytest.raises(ConfigError) as e:
        load_section(Outer, path)
    assert e.value.line == 1



@pytest.mark.parametrize("value,words", [("010", "reads it as 8"), ("1:30", "reads it as 90"),
                                         ("1_000", "not a plain integer")])
def test_yaml_1_1_integers_are_refused_with_their_line(tmp_path, value, words):
    """``seed: 010`` ran seed 8 and ``seed: 1:30`` seed 90, silent (thirteenth pass)."""
    path = tmp_path / "c.yaml"
    path.write_text(f"outer:\n  count: {value}\n")
    with pytest.raises(ConfigError, match=words) as e:
        load_section(Outer, path)
    assert e.value.line == 2


def test_yaml_words_are_not_booleans_and_exponents_are_floats(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("outer:\n  mode: off\n")
    with pytest.raises(ConfigError, match="write true or false"):
        load_section(Outer, path)
    path.write_text("outer:\n  sigma_m: 1e-3\n  count: 7\n")
    assert load_section(Outer, path).sigma_m == 1e-3
    path.write_text("outer:\n  # every key commented out\n")
    assert load_section(Outer, path) == Outer()


def test_the_last_build_of_a_section_decides_what_is_said(tmp_path):
    """A section built twice (a comparison builds each back end's in the parent too):
    the notes are those of its last build, not a union."""
    path = tmp_path / "c.toml"
    path.write_text("[gated]\npolish_iterations = 3\n")
    config = ConfigFile.read(path)
    config.section(Gated, {"polish": False})
    config.section(Gated)
    assert config.inert_lines() == []
    config.mark_inert("gated", ["polish_iterations"], "a mark")
    config.section(Gated)  # a build does not erase what another section marked
    assert len(config.inert_lines()) == 1
