"""Frozen-dataclass configuration, loadable from TOML or YAML.

A config file has one table per section, each named as the section's
dataclass expects (``[synthetic]``, ``[isam2]``, ``[run]``, ...). Unknown keys
are refused with the file name, so a typo never silently does nothing.
"""

from __future__ import annotations

import dataclasses
import tomllib
import typing
from pathlib import Path
from typing import Any, TypeVar

from slamcore.errors import ConfigError

T = TypeVar("T")


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a TOML (``.toml``) or YAML (``.yaml``/``.yml``) file into a dict."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            with path.open("rb") as f:
                data = tomllib.load(f)
        elif suffix in (".yaml", ".yml"):
            import yaml  # imported here: only YAML users pay for it

            with path.open("r", encoding="utf-8") as f:
                data = yaml.safe_load(f) or {}
        else:
            raise ConfigError(f"{path}: config must be .toml, .yaml or .yml")
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: {e}") from None
    except ConfigError:
        raise
    except Exception as e:  # yaml.YAMLError and friends carry line info in str(e)
        raise ConfigError(f"{path}: {' '.join(str(e).split())}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a table of sections")
    return data


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``, refusing unknown keys and bad types."""
    data = dict(data or {})
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown} for [{section_name(cls)}]; "
                          f"known: {sorted(names)}")
    kwargs = {}
    for key, value in data.items():
        kwargs[key] = _coerce(value, hints[key], f"{where}: [{section_name(cls)}] {key}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: [{section_name(cls)}] {e}") from None


def section_name(cls: type) -> str:
    """Section of a config file that configures ``cls`` (its ``SECTION`` attribute)."""
    return getattr(cls, "SECTION", cls.__name__.lower())


def load_section(cls: type[T], path: str | Path | None, overrides: dict[str, Any] | None = None) -> T:
    """Defaults, then the file's section (if a file is given), then ``overrides``."""
    data: dict[str, Any] = {}
    where = "command line"
    if path is not None:
        data.update(read_config_file(path).get(section_name(cls), {}) or {})
        where = str(path)
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    return from_dict(cls, data, where)


def _coerce(value: Any, hint: Any, what: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        return _coerce(value, non_none[0], what)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{what}: expected a list, got {value!r}")
        inner = args[0] if args else float
        return tuple(_coerce(v, inner, what) for v in value)
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{what}: expected true/false, got {value!r}")
        return value
    if hint in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{what}: expected a number, got {value!r}")
        if hint is int and float(value) != int(value):
            raise ConfigError(f"{what}: expected an integer, got {value!r}")
        return hint(value)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{what}: expected a string, got {value!r}")
        return value
    return value
