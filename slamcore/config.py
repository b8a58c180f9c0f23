"""Frozen-dataclass configuration, loadable from TOML or YAML, checked in one place.

A config file has one table per section, each named by the ``SECTION`` of the
dataclass it configures (``[synthetic]``, ``[isam2]``, ...); a field that is
itself a config dataclass is a sub-table (``[loops.orb]``). A file is parsed
once per run into a :class:`ConfigFile`; every section is taken from it with
:meth:`ConfigFile.section` (defaults, then the file, then command-line
overrides). Unknown sections and keys are refused naming the file and line, so
a typo never silently does nothing.

Values are checked by :func:`validate`, which every config dataclass runs when
it is built (they derive from :class:`Validated`), so a config built in code is
held to the same rules as one read from a file:

- the type hint: ``int``, ``float``, ``bool``, ``str``, tuples of those, an
  optional (``X | None``) or a nested config;
- enum-like string modes: a ``typing.Literal`` hint lists the allowed values;
- ranges: field metadata ``{"min": a, "max": b}`` (inclusive) or
  ``{"gt": a, "lt": b}`` (exclusive), via :func:`bounded`; integers must also
  fit what the machine can index (:data:`INT_LIMIT`).

A setting that acts only in some modes of the others (``polish_method`` with
``polish = false``) is declared by its config's :attr:`Validated.GATES`; a file
that sets it where it does nothing is told so when the command ends
(:meth:`ConfigFile.inert_lines`), as is a whole section the run's other
settings leave unread (:meth:`ConfigFile.mark_inert`). A warning, not a
refusal: a command-line flag may switch the mode of a file written for another.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from slamcore.errors import ConfigError, quote
from slamcore.input_files import check_input_path

T = TypeVar("T")

if TYPE_CHECKING:  # _typeshed exists for the type checker only
    from _typeshed import DataclassInstance

    D = TypeVar("D", bound=DataclassInstance)

#: Largest integer a config value may hold: counts and sizes index numpy arrays
#: (int64), and anything near this is a typo or an attack, not a setting.
INT_LIMIT = 2**62


def bounded(
    default: Any = dataclasses.MISSING,
    *,
    min: float | None = None,
    max: float | None = None,
    gt: float | None = None,
    lt: float | None = None,
    default_factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with range metadata that :func:`validate` checks."""
    meta = {k: v for k, v in (("min", min), ("max", max), ("gt", gt), ("lt", lt)) if v is not None}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def section_name(cls: type) -> str:
    """Section of a config file that configures ``cls`` (its ``SECTION`` attribute), or,
    for a config that is only ever a nested table, the name its messages use (``TABLE``)."""
    return getattr(cls, "SECTION", "") or getattr(cls, "TABLE", cls.__name__.lower())


def choices_of(cls: type, name: str) -> tuple | None:
    """Allowed values of a ``Literal``-typed field, or None."""
    hint = typing.get_type_hints(cls)[name]
    if typing.get_origin(hint) is typing.Literal:
        return typing.get_args(hint)
    return None


# --------------------------------------------------------------------------- checking values


def _is_config(hint: Any) -> bool:
    return isinstance(hint, type) and dataclasses.is_dataclass(hint)


def _check_value(value: Any, hint: Any, what: str) -> Any:
    """``value`` coerced to ``hint`` (int -> float only), or ConfigError."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        if value is None and type(None) in args:
            return None
        return _check_value(value, next(a for a in args if a is not type(None)), what)
    if origin is typing.Literal:
        if not isinstance(value, str) and not isinstance(value, type(args[0])):
            raise ConfigError(f"{what} must be one of {list(args)}, got {quote(value)}")
        if value not in args:
            raise ConfigError(f"{what} must be one of {list(args)}, got {quote(value)}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{what}: expected a list, got {quote(value)}")
        inner = args[0] if args else float
        return tuple(_check_value(v, inner, what) for v in value)
    if _is_config(hint):
        if not isinstance(value, hint):
            raise ConfigError(f"{what}: expected a [{section_name(hint)}] table, got {quote(value)}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{what}: expected true/false, got {quote(value)}")
        return value
    if hint in (int, float):
        return _check_number(value, hint, what)
    if hint is str and not isinstance(value, str):
        raise ConfigError(f"{what}: expected a string, got {quote(value)}")
    return value


def _check_number(value: Any, hint: type, what: str) -> int | float:
    import numpy as np  # numpy scalars are accepted as numbers

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{what}: expected a number, got {quote(value)}")
    if hint is int:
        if isinstance(value, (float, np.floating)) and not (
            math.isfinite(value) and float(value).is_integer()
        ):
            raise ConfigError(f"{what}: expected an integer, got {quote(value)}")
        # abs() keeps the operand's numeric type; mypy joins the union's results to object
        magnitude = typing.cast("int | float | np.integer | np.floating", abs(value))
        if magnitude > INT_LIMIT:
            raise ConfigError(
                f"{what}: {quote(value)} is beyond what this machine can hold (|value| <= 2**62)"
            )
        return int(value)
    try:
        as_float = float(value)
    except OverflowError:  # an integer past 1.8e308 (thirteenth hostile pass: a traceback)
        as_float = math.inf
    if not math.isfinite(as_float):
        raise ConfigError(f"{what}: expected a finite number, got {quote(value)}")
    return as_float


def _check_range(value: Any, meta: typing.Mapping, what: str) -> None:
    if value is None or not meta:
        return
    lo, hi, gt, lt = (meta.get(k) for k in ("min", "max", "gt", "lt"))
    vals = value if isinstance(value, tuple) else (value,)
    for v in vals:
        if (
            (lo is not None and v < lo)
            or (hi is not None and v > hi)
            or (gt is not None and not v > gt)
            or (lt is not None and not v < lt)
        ):
            parts = [
                f">= {lo}" if lo is not None else "",
                f"> {gt}" if gt is not None else "",
                f"<= {hi}" if hi is not None else "",
                f"< {lt}" if lt is not None else "",
            ]
            raise ConfigError(f"{what} must be {' and '.join(p for p in parts if p)}, got {quote(value)}")


def validate(config: Any) -> None:
    """Check every field of a config dataclass against its hint and range metadata.

    :class:`Validated` calls it when a config is built; values are normalised in
    place (an integer given for a float field becomes a float).
    """
    cls = type(config)
    hints = typing.get_type_hints(cls)
    section = section_name(cls)
    for f in dataclasses.fields(cls):
        what = f"{section}.{f.name}"
        value = _check_value(getattr(config, f.name), hints[f.name], what)
        _check_range(value, f.metadata, what)
        object.__setattr__(config, f.name, value)


@dataclass(frozen=True)
class Gate:
    """Settings ``fields`` of a config act only when ``acts(config)`` holds, which
    ``when`` says in the file's words (``"polish = true"``)."""

    fields: tuple[str, ...]
    when: str
    acts: typing.Callable[[Any], bool]


class Validated:
    """Base of the config dataclasses: :func:`validate` runs whenever one is built, so
    no config can forget its checks. A subclass with checks of its own (between
    fields) defines ``__post_init__`` and calls ``super().__post_init__()`` first."""

    #: settings read only in some modes of the others (:meth:`inert_settings`)
    GATES: ClassVar[tuple[Gate, ...]] = ()

    def __post_init__(self) -> None:
        validate(self)

    def inert_settings(self) -> dict[str, str]:
        """``{field: when it acts}`` for the fields these settings leave unread (helper
        E of the eleventh hostile pass: ``polish_method`` with the polish off, the
        association gate under known ids, ... ran bit-identical and silent)."""
        out: dict[str, str] = {}
        for gate in self.GATES:
            if not gate.acts(self):
                for name in gate.fields:
                    out.setdefault(name, gate.when)
        return out


# --------------------------------------------------------------------------- files


#: A TOML key: bare, "basic" or 'literal' parts joined by dots.
_TOML_KEY = r"""(?:[A-Za-z0-9_\-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_\-]+|"[^"]*"|'[^']*'))*"""


def _toml_key(text: str) -> tuple[str, ...]:
    return tuple(
        m.group(0).strip().strip("\"'")
        for m in re.finditer(r"""[^."']+|"[^"]*"|'[^']*'""", text)
        if m.group(0).strip()
    )


def _toml_lines(text: str) -> dict[tuple[str, ...], int]:
    """1-based line of each ``[table]`` and ``key =`` of a TOML text, by dotted path;
    quoted keys and the keys of a one-line inline table (``t = {k = 1}``) too (thirteenth
    hostile pass: ``'min_depth_m' = 0.3`` had no line, and what looked for it missed it)."""
    lines: dict[tuple[str, ...], int] = {}
    table: tuple[str, ...] = ()
    for n, raw in enumerate(text.splitlines(), start=1):
        s = raw.split("#", 1)[0].strip()
        m = re.fullmatch(rf"\[\[?\s*({_TOML_KEY})\s*\]\]?", s)
        if m:
            table = _toml_key(m.group(1))
            lines.setdefault(table, n)
            continue
        m = re.match(rf"({_TOML_KEY})\s*=\s*(.*)", s)
        if m:
            key = table + _toml_key(m.group(1))
            lines.setdefault(key, n)
            # a quoted key holding dots ("ekf.association" = ... in [sweep.set]) is also
            # found by its parts, as the sweep file names its swept settings
            lines.setdefault(table + tuple(p for part in _toml_key(m.group(1)) for p in part.split(".")), n)
            inline = re.fullmatch(r"\{(.*)\}", m.group(2).strip())
            if inline:
                for k in re.finditer(rf"(?:^|,)\s*({_TOML_KEY})\s*=", inline.group(1)):
                    lines.setdefault(key + _toml_key(k.group(1)), n)
    return lines


def _yaml_lines(text: str) -> dict[tuple[str, ...], int]:
    """1-based line of each mapping key of a YAML text, by dotted path."""
    import yaml

    lines: dict[tuple[str, ...], int] = {}

    def walk(node, prefix):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                key = prefix + (str(k.value),)
                lines.setdefault(key, k.start_mark.line + 1)
                walk(v, key)

    walk(yaml.compose(text), ())
    return lines


def strict_yaml_loader():
    """A ``yaml.SafeLoader`` that refuses anchors, aliases and duplicate keys.

    Aliases let ~800 bytes expand to billions of nodes (a "billion laughs"
    bomb: minutes at full CPU), and a config never needs them. A duplicate key
    would silently let the last value win, where TOML refuses it.
    """
    import yaml

    class StrictLoader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            event = self.peek_event()
            if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
                raise yaml.MarkedYAMLError(
                    problem="anchors and aliases (& and *) are not allowed in a config",
                    problem_mark=event.start_mark,
                )
            return super().compose_node(parent, index)

        def construct_mapping(self, node, deep=False):
            seen = set()
            for key, _ in node.value:
                if isinstance(key, yaml.ScalarNode):
                    if (key.tag, key.value) in seen:
                        raise yaml.MarkedYAMLError(
                            problem=f"duplicate key {quote(key.value)}", problem_mark=key.start_mark
                        )
                    seen.add((key.tag, key.value))
            return super().construct_mapping(node, deep)

        # YAML 1.1 (PyYAML) reads ``010`` as 8, ``1:30`` as 90, ``off`` as false and
        # ``1e-3`` as a string (thirteenth hostile pass: seed 010 ran seed 8, silent).
        # A config means YAML 1.2's plain numbers and true/false: the rest is refused
        # with its line, and 1e-3 is the float it looks like.
        def construct_yaml_int(self, node):
            text = str(node.value)
            if (
                re.fullmatch(r"[-+]?0[0-9_]+", text)
                or re.fullmatch(r"[-+]?0[bB][01_]+", text)  # YAML 1.2 reads 0b11 as a string
                or ":" in text
                or "_" in text
            ):
                raise yaml.MarkedYAMLError(
                    problem=f"{quote(text)} is not a plain integer (YAML 1.1 reads it as "
                    f"{super().construct_yaml_int(node)}); write the number you mean, or quote it",
                    problem_mark=node.start_mark,
                )
            return super().construct_yaml_int(node)

        def construct_yaml_float(self, node):
            text = str(node.value)
            if ":" in text or "_" in text:  # 1:30.0 read as 90.0, 1_0.5 as 10.5 (hostile pass 22)
                raise yaml.MarkedYAMLError(
                    problem=f"{quote(text)} is not a plain number (YAML 1.1 reads it as "
                    f"{super().construct_yaml_float(node)}); write the number you mean, or quote it",
                    problem_mark=node.start_mark,
                )
            return super().construct_yaml_float(node)

        def construct_yaml_bool(self, node):
            if str(node.value).lower() not in ("true", "false"):
                raise yaml.MarkedYAMLError(
                    problem=f"{quote(node.value)} is read by YAML 1.1 as a boolean; write true or "
                    "false, or quote it for a word",
                    problem_mark=node.start_mark,
                )
            return super().construct_yaml_bool(node)

    StrictLoader.add_constructor("tag:yaml.org,2002:int", StrictLoader.construct_yaml_int)
    StrictLoader.add_constructor("tag:yaml.org,2002:bool", StrictLoader.construct_yaml_bool)
    StrictLoader.add_constructor("tag:yaml.org,2002:float", StrictLoader.construct_yaml_float)
    StrictLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?[0-9]+(?:\.[0-9]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789"),
    )
    return StrictLoader


def _parse(path: Path) -> tuple[dict, dict[tuple[str, ...], int], str]:
    """``(data, lines, SHA-256 of the bytes parsed)``: the digest of what was read, not of
    the file as it is when the run ends (a file edited during a run was recorded by the
    edited file's digest beside the old file's settings, hostile pass 14)."""
    suffix = path.suffix.lower()
    try:
        raw = path.read_bytes()
        text = raw.decode("utf-8-sig")  # a byte-order mark is not a key
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read config file: {e}", path) from None
    sha256 = hashlib.sha256(raw).hexdigest()
    try:
        if suffix == ".toml":
            return tomllib.loads(text), _toml_lines(text), sha256
        if suffix in (".yaml", ".yml"):
            import yaml  # imported here: only YAML users pay for it

            return yaml.load(text, Loader=strict_yaml_loader()) or {}, _yaml_lines(text), sha256
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"at line (\d+)", str(e))
        raise ConfigError(str(e), path, int(m.group(1)) if m else None) from None
    except Exception as e:  # yaml.YAMLError carries its own mark
        mark = getattr(e, "problem_mark", None)
        raise ConfigError(
            " ".join(str(getattr(e, "problem", None) or e).split()),
            path,
            None if mark is None else mark.line + 1,
        ) from None
    raise ConfigError("config must be .toml, .yaml or .yml", path)


@dataclass(frozen=True)
class ConfigFile:
    """A parsed config file (or none): sections by name, and where each key was written.

    Build with :meth:`read` once per run and take sections from it with
    :meth:`section`; :meth:`check_sections` refuses sections nothing reads.
    """

    path: Path | None = None
    data: dict = field(default_factory=dict)
    lines: dict = field(default_factory=dict)
    #: SHA-256 of the file's bytes as parsed (None without a file)
    sha256: str | None = field(default=None, compare=False)
    #: the sections :meth:`section` was asked for (:meth:`unread_sections`)
    read_sections: set = field(default_factory=set, compare=False, repr=False)
    #: the file's settings that did nothing: key path -> when they act (:meth:`inert_lines`),
    #: by the last build of their section (its gates, the flags that replaced them)
    inert: dict = field(default_factory=dict, compare=False, repr=False)
    #: the same, marked by the command where another section decides (:meth:`mark_inert`)
    marked: dict = field(default_factory=dict, compare=False, repr=False)
    #: every section as :meth:`section` last built it (defaults, file, overrides): what ran
    settings: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def read(cls, path: str | Path | None) -> ConfigFile:
        """Parse ``path`` (TOML or YAML); ``None`` gives an empty config."""
        if path is None:
            return cls()
        path = Path(path)
        check_input_path(path, "config file", error=ConfigError)
        data, lines, sha256 = _parse(path)
        if not isinstance(data, dict):
            raise ConfigError("top level must be a table of sections", path, 1)
        _check_keys(data, (), path, lines)
        for name, value in list(data.items()):
            if value is None and path.suffix.lower() in (".yaml", ".yml"):
                data[name] = value = {}  # a YAML section whose keys are all commented out
            if not isinstance(value, dict):
                raise ConfigError(
                    f"[{name}] must be a table of settings, got {quote(value)}", path, lines.get((str(name),))
                )
        return cls(path, data, lines, sha256=sha256)

    def line_of(self, *keys: str) -> int | None:
        return self.lines.get(tuple(keys))

    def check_sections(self, known: typing.Iterable[str]) -> None:
        """Refuse a section that no component reads (a typo would do nothing)."""
        known = sorted(set(known))
        for name in self.data:
            if name not in known:
                raise ConfigError(
                    f"unknown section [{name}]; known sections: {', '.join(known)}",
                    self.path,
                    self.line_of(name),
                )

    def unread_sections(self) -> list[str]:
        """The file's sections that no :meth:`section` call has read so far: a command
        that ends with some says so (their settings did nothing, and were not checked)."""
        return [name for name in self.data if name not in self.read_sections]

    def section(
        self, cls: type[T], overrides: dict[str, Any] | None = None, flags: dict[str, str] | None = None
    ) -> T:
        """Defaults of ``cls``, then the file's section, then non-None ``overrides``. A value
        of ``overrides`` refused is said as the command line's, under its ``flags`` name
        (``{"sigma_t_per_m": "--odometry-noise SIGMA_T_PER_M"}``), never with the file's
        line: ``--odometry-noise -1 0.1`` beside a config file was blamed on the file."""
        name = section_name(cls)
        self.read_sections.add(name)
        data = dict(self.data.get(name, {}) or {})
        given = {k: v for k, v in (overrides or {}).items() if v is not None}
        self._check_overridden(cls, name, {k: data[k] for k in data.keys() & given.keys()})
        file_data = dict(data)
        # the section's last build is what ran: an earlier build's notes go
        for stale in [k for k in self.inert if k[0] == name]:
            del self.inert[stale]
        for key in data.keys() & given.keys():  # the command line wins, and says so
            if data[key] != given[key] or isinstance(data[key], bool) != isinstance(given[key], bool):
                self.inert[(name, key)] = f"the command line's {_toml_value(given[key])}, which replaced it"
        data.update(given)
        try:
            built = self._build(cls, data, (name,))
        except ConfigError as e:
            key = next((k for k in given if re.search(rf"\b{name}\.{re.escape(k)}\b", e.reason)), None)
            if key is None:
                raise
            flag = (flags or {}).get(key, f"the command line's {name}.{key}")
            raise ConfigError(e.reason.replace(f"{name}.{key}", flag)) from None
        self.settings[name] = dataclasses.asdict(typing.cast("DataclassInstance", built))
        if issubclass(cls, Validated):
            # a flag that turned a mode off is named: "--no-polish" under "polish = true"
            by_file = built
            if given:
                try:
                    by_file = self._build(cls, file_data, (name,))
                except ConfigError:
                    pass
            self._note_inert(built, by_file, self.data.get(name) or {}, (name,))
        return built

    def _note_inert(self, config: Any, by_file: Any, table: dict, where: tuple[str, ...]) -> None:
        """Record the keys of the file's ``table`` that ``config`` (built with the
        overrides) leaves unread, and those of its sub-tables; ``by_file``: the same
        built without the overrides (those that were not unread there, a flag made so)."""
        inert = config.inert_settings() if isinstance(config, Validated) else {}
        if not inert and not any(isinstance(v, dict) for v in table.values()):
            return
        file_inert = by_file.inert_settings() if isinstance(by_file, Validated) else {}
        for key, value in table.items():
            if key in inert:
                flag = "" if key in file_inert else " (a command-line option set it otherwise)"
                self.inert[where + (key,)] = inert[key] + flag
            elif isinstance(value, dict):
                self._note_inert(
                    getattr(config, key, None), getattr(by_file, key, None), value, where + (key,)
                )

    def mark_inert(self, section: str, keys: typing.Iterable[str] | None, when: str) -> None:
        """The file's ``keys`` of ``section`` (None: all of them) did nothing in this
        command, where the settings that decide it are in another section or a flag
        (``[harris]`` under ``[tracker] detector = "orb"``); ``when``: when they act."""
        table = self.data.get(section) or {}
        for key in table if keys is None else keys:
            if key in table and (section, key) not in self.inert:  # a gate's note said it already
                self.marked[(section, key)] = when

    def fork(self) -> ConfigFile:
        """A copy whose notes (sections read, settings that did nothing, what ran) start
        as this one's and then go apart: one of several runs of a command (``compare``),
        merged back with :meth:`merge_notes`."""
        return dataclasses.replace(
            self,
            read_sections=set(self.read_sections),
            inert=dict(self.inert),
            marked=dict(self.marked),
            settings=dict(self.settings),
        )

    def notes(self) -> tuple[set, dict, dict]:
        """``(sections read, inert, marked)``: what :meth:`merge_notes` takes (plain
        values, sent back from a run in another process)."""
        return set(self.read_sections), dict(self.inert), dict(self.marked)

    def merge_notes(self, runs: typing.Sequence[tuple[set, dict, dict]]) -> None:
        """Take the :meth:`notes` of several runs forked from this config: a section any
        of them read is read, and a setting did nothing where every run that read its
        section left it unread (one run's gate is no note of a comparison whose other
        back end read it)."""
        if not runs:
            return
        for read, _, _ in runs:
            self.read_sections.update(read)
        noted = [{**marked, **inert} for _, inert, marked in runs]
        inert_any: dict = {}
        marked_any: dict = {}
        for _, inert, marked in runs:
            for key, when in inert.items():
                inert_any.setdefault(key, when)
            for key, when in marked.items():
                marked_any.setdefault(key, when)
        kept = {
            key
            for key in inert_any.keys() | marked_any.keys()
            if all(key in n for n, (read, _, _) in zip(noted, runs, strict=True) if key[0] in read)
        }
        self.inert.clear()
        self.inert.update({k: w for k, w in inert_any.items() if k in kept})
        self.marked.clear()
        self.marked.update({k: w for k, w in marked_any.items() if k in kept and k not in self.inert})

    def inert_lines(self) -> list[str]:
        """One line per group of the file's settings that did nothing, with the line
        of the first and when they act."""
        groups: dict[tuple[tuple[str, ...], str], list[str]] = {}
        for path, when in {**self.inert, **self.marked}.items():
            groups.setdefault((path[:-1], when), []).append(path[-1])
        out = []
        for (where, when), keys in groups.items():
            line = self.line_of(*where, keys[0])
            at = f"{self.path}" + (f" line {line}" if line is not None else "")
            head = f"--config {at}: [{'.'.join(where)}] {', '.join(keys)} did nothing"
            if when.startswith("the command line's "):
                out.append(f"{head}: {when}")
            else:
                out.append(f"{head}: {'it acts' if len(keys) == 1 else 'they act'} only with {when}")
        return out

    def _check_overridden(self, cls: type, name: str, data: dict) -> None:
        """The file's values that an override replaces still have their field's type:
        ``robot_model = "banana"`` ran silently under ``--odometry none`` (which sets it)."""
        hints = typing.get_type_hints(cls)
        for key, value in data.items():
            if key in hints and not _is_config(hints[key]):
                try:
                    _check_value(value, hints[key], f"{name}.{key}")
                except ConfigError as e:
                    raise ConfigError(str(e), self.path, self.line_of(name, key)) from None

    def _build(self, cls: type[T], data: dict, where: tuple[str, ...], base: Any = None) -> T:
        """``cls`` from ``data``; a nested table starts from its field's own default
        (``base``), so ``[loops.orb] n_features = 500`` keeps the loop detector's
        other ORB settings instead of ORB's general defaults."""
        hints = typing.get_type_hints(cls)
        names = field_names(cls)
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(
                f"unknown key(s) {unknown} in [{'.'.join(where)}]; known: {sorted(names)}",
                self.path,
                self.line_of(*where, unknown[0]),
            )
        kwargs = {}
        for key, value in data.items():
            hint = hints[key]
            if _is_config(hint) and isinstance(value, dict):
                value = self._build(hint, value, where + (key,), _field_default(cls, key))
            try:
                kwargs[key] = _check_value(value, hint, f"{'.'.join(where)}.{key}")
            except ConfigError as e:
                raise ConfigError(str(e), self.path, self.line_of(*where, key)) from None
        try:
            return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
        except ConfigError as e:
            if self.path is None or e.path is not None:
                raise
            key = next((k for k in kwargs if re.search(rf"\b{re.escape(k)}\b", str(e))), None)
            reason, own, full = e.reason, f"{section_name(cls)}.", f"{'.'.join(where)}."
            if own != full and reason.startswith(own):  # [loops.orb] read as "orb.scale_factor"
                reason = full + reason[len(own) :]
            raise ConfigError(
                reason, self.path, self.line_of(*where, key) if key else self.line_of(*where)
            ) from None
        except (TypeError, ValueError) as e:
            raise ConfigError(f"[{'.'.join(where)}] {e}", self.path, self.line_of(*where)) from None


def _check_keys(table: dict, where: tuple[str, ...], path: Path, lines: dict) -> None:
    """ConfigError (file and line) for a key that is no text: YAML reads ``1:`` as the
    number 1 and ``null:`` as None, which no setting is named (a section mixing them
    with names raised TypeError out of sorting its keys: hostile pass 22)."""
    for key, value in table.items():
        if not isinstance(key, str):
            raise ConfigError(
                f"key {key!r} in [{'.'.join(where) or 'the top level'}] is not a name (YAML read it as "
                f"{type(key).__name__}); settings and sections are named by words",
                path,
                lines.get((*where, str(key))),
            )
        if isinstance(value, dict):
            _check_keys(value, (*where, key), path, lines)


def _toml_value(value: Any) -> str:
    """``value`` as a config file writes it (``true``, ``"text"``, ``0.5``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def field_names(cls: type) -> set[str]:
    """Names of the fields of the dataclass ``cls``."""
    return {f.name for f in dataclasses.fields(cls)}


def _field_default(cls: type, name: str) -> Any:
    """The default value of field ``name`` of ``cls`` (None if it has none)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def load_section(
    cls: type[T], source: ConfigFile | str | Path | None, overrides: dict[str, Any] | None = None
) -> T:
    """One section: ``source`` is a :class:`ConfigFile`, a file path, or None (defaults)."""
    config = source if isinstance(source, ConfigFile) else ConfigFile.read(source)
    return config.section(cls, overrides)


def from_dict(cls: type[T], data: dict[str, Any] | None) -> T:
    """Build ``cls`` from a plain dict (no file), refusing unknown keys and bad values."""
    return ConfigFile(data={section_name(cls): dict(data or {})}).section(cls)


def with_overrides(config: D, overrides: dict[str, Any], expected: type | None = None) -> D:
    """``config`` with the named fields replaced (checked again by its ``__post_init__``),
    or ``config`` itself without overrides: what ``Part(config, **overrides)`` makes of
    its arguments, for the parts that take their settings either way. A name that is
    no setting of ``config`` is a ConfigError, not Python's TypeError; so is a config
    that is not an ``expected`` instance (a dict of settings, or another part's config,
    was taken and failed at first use with AttributeError: twentieth hostile pass)."""
    wanted = expected or type(config)
    if not (dataclasses.is_dataclass(config) and isinstance(config, wanted)):
        raise ConfigError(
            f"expected {wanted.__name__} settings, got {type(config).__name__} (or pass the settings "
            "as keyword arguments: Part(name=value))"
        )
    if not overrides:
        return config
    unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(config)})
    if unknown:
        raise ConfigError(f"{section_name(type(config))}: unknown setting(s) {unknown}")
    return dataclasses.replace(config, **overrides)
