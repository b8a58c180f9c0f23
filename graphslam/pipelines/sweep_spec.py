"""Sweep files: a grid of datasets x back ends x config overrides x seeds.

```toml
[sweep]
dataset = ["synthetic"]                 # 2-D datasets (names or pose-graph files) or
                                        # image sequences (synthetic-images, a folder);
                                        # a path is read beside the sweep file
backend = ["isam2", "ekf"]
seed = {from = 0, to = 49}              # or a list; absent: runs get no --seed
max_steps = 200                         # optional: --max-steps of every run
max_runs = 20000                        # optional: the grid's cap (default 10 000)
nees = true                             # optional: runs score their pose NEES (default:
                                        # true when every dataset is the synthetic world,
                                        # the one built-in 2-D dataset with truth and
                                        # covariances cheap enough to take at every pose;
                                        # image-sequence runs write no nees.csv)
config = "base.toml"                    # optional: the runs' base config (relative
                                        # to the sweep file); overrides go on top
[sweep.set]
"ekf.association" = ["known", "unknown"]
```

The grid is the product of every list. An override applies only to runs
that read its section (``[ekf]`` to the EKF, ``[synthetic]`` to the synthetic
world), so ``fastslam.n_particles = [10, 100]`` does not run iSAM2 twice.
Everything is checked before any run: unknown keys and sections, values out
of range, an empty list (empty grid), each refused with file and line.

A run's *config hash* is the hash of its dataset (a built-in name, or the resolved
path of a file or folder, whichever working directory the sweep is started from and
however the path is spelled: :func:`dataset_key`; and what every file the run reads
holds: :func:`dataset_fingerprint`), back end, step limit, NEES switch and full config
(base plus overrides), without the seed: ``(config_hash, seed)`` names a run, and a
sweep that is run again skips the ones already done (and made by this code:
:func:`graphslam.pipelines.sweep.folder_mismatch`).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from slamcore.config import INT_LIMIT, ConfigFile, field_names, from_dict
from slamcore.errors import ConfigError, GraphSlamError, InputError, quote

SWEEP_KEYS = ("dataset", "backend", "seed", "max_steps", "config", "nees", "set", "max_runs")
#: Runs a grid may hold unless ``[sweep] max_runs`` says more: a sweep of 10 000 runs
#: of seconds each already takes hours on a workstation, and a product of lists
#: mistyped by an order of magnitude (4 x 10^7 runs) spent minutes listing its runs
#: before starting any (issue 34).
MAX_RUNS = 10_000
#: Seeds a ``{from, to}`` range may hold (a typo like to = 1e9 would never end).
MAX_SEEDS = 100_000


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: ``graphslam run`` with these arguments and config."""

    dataset: str  # as the run is given it: a built-in name or an absolute path
    backend: str
    seed: int | None
    max_steps: int | None
    nees: bool = True
    overrides: dict = field(default_factory=dict)  # "section.key" -> value, applied ones
    config: dict = field(default_factory=dict)  # the full config file of the run
    config_hash: str = ""
    #: the dataset as the sweep file lists it (sweep.csv's dataset column), "": ``dataset``
    entry: str = ""

    @property
    def run_id(self) -> str:
        return f"{self.backend}-{self.config_hash}-s{'none' if self.seed is None else self.seed}"


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep file."""

    path: Path
    datasets: tuple[str, ...]  # built-in names and absolute paths (:func:`_datasets`)
    backends: tuple[str, ...]
    seeds: tuple[int | None, ...]
    max_steps: int | None
    nees: bool
    base_config: dict
    set_keys: tuple[str, ...]
    set_values: tuple[tuple, ...]
    #: each of ``datasets`` as the sweep file lists it; empty: as ``datasets``
    entries: tuple[str, ...] = ()
    #: what the file left to a default that a reader may not expect, one line each
    notes: tuple[str, ...] = ()

    def runs(self) -> list[RunSpec]:
        """Every run of the grid, in a fixed order, without repeats."""
        out, seen = [], set()
        prints = {dataset: dataset_fingerprint(dataset) for dataset in self.datasets}
        entries = dict(zip(self.datasets, self.entries or self.datasets, strict=True))
        for dataset, backend in itertools.product(self.datasets, self.backends):
            sections = run_sections(dataset, backend)
            for combo in itertools.product(*self.set_values):
                applied = {
                    k: v for k, v in zip(self.set_keys, combo, strict=True) if k.split(".", 1)[0] in sections
                }
                config = merged_config(self.base_config, applied)
                chash = config_hash(
                    dataset_key(dataset), backend, self.max_steps, self.nees, config, prints[dataset]
                )
                for seed in self.seeds:
                    if (chash, seed) in seen:
                        continue
                    seen.add((chash, seed))
                    out.append(
                        RunSpec(
                            dataset,
                            backend,
                            seed,
                            self.max_steps,
                            self.nees,
                            applied,
                            config,
                            chash,
                            entries[dataset],
                        )
                    )
        return out


def merged_config(base: dict, overrides: dict) -> dict:
    """``base`` with each ``"section.key": value`` set."""
    config = copy.deepcopy(base)
    for dotted, value in overrides.items():
        section, key = dotted.split(".", 1)
        config.setdefault(section, {})[key] = value
    return config


def config_hash(
    dataset: str, backend: str, max_steps: int | None, nees: bool, config: dict, data: str | None = None
) -> str:
    """12 hex digits naming a run's settings (everything but the seed); ``data``: the
    dataset's :func:`dataset_fingerprint`, so a file changed under the same name is a
    new run, not one already done."""
    text = json.dumps(
        {
            "dataset": dataset,
            "backend": backend,
            "max_steps": max_steps,
            "nees": nees,
            "config": config,
            "data": data,
        },
        sort_keys=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def dataset_key(dataset: str) -> str:
    """A dataset's name in the config hash: a built-in name as it is, a path resolved
    (absolute, symbolic links followed). The path as typed made one sweep file three
    sets of runs from three working directories (fifteenth hostile pass)."""
    from graphslam.registry import is_builtin_dataset

    return dataset if is_builtin_dataset(dataset) else os.path.realpath(dataset)


def dataset_fingerprint(dataset: str) -> str | None:
    """What a run of ``dataset`` reads, as a hash; None for a built-in name. Every file its
    reader names (:func:`graphslam.registry.dataset_files`: a Plaza log's range file
    beside it, a KITTI sequence's truth outside its folder, images through a symbolic
    link), each by resolved path, size and modification time (an image folder of
    gigabytes is not read twice), and the named file itself by its bytes. A sweep's
    fingerprint of the named file or folder alone kept old results when such a file
    changed (fifteenth hostile pass)."""
    from graphslam.registry import dataset_files, is_builtin_dataset

    if is_builtin_dataset(dataset):
        return None
    path = Path(dataset)
    try:
        entries: list = []
        if path.is_file():
            digest = hashlib.sha256()
            with open(path, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    digest.update(block)
            entries.append(digest.hexdigest())
        for p in dataset_files(dataset):
            if p != path:
                st = p.stat()
                entries.append((os.path.realpath(p), st.st_size, st.st_mtime_ns))
    except OSError as e:  # unreadable: one line before any run, not a traceback
        where = Path(e.filename) if e.filename else path
        raise InputError(f"cannot read this dataset to tell it from another: {e.strerror}", where) from None
    return hashlib.sha256(json.dumps(entries).encode()).hexdigest()


def visual_sections(dataset: str, backend: str) -> dict[str, type]:
    """Config classes ``graphslam run`` on the image sequence ``dataset`` with ``backend``
    reads, by section name (without ``--loops``; ``graphslam sweep`` checks its
    overrides against them)."""
    from frontend.active_search_config import ActiveSearchConfig
    from frontend.harris import HarrisConfig
    from frontend.orb import OrbConfig
    from frontend.tracking_config import TrackerConfig
    from graphslam.pipelines.spatial import OdometryNoiseConfig, VisualRunConfig
    from graphslam.registry import visual_backend_config
    from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig

    classes = (
        VisualRunConfig,
        OdometryNoiseConfig,
        TrackerConfig,
        ActiveSearchConfig,
        HarrisConfig,
        OrbConfig,
        visual_backend_config(backend),
    )
    out: dict[str, type] = {cls.SECTION: cls for cls in classes}
    if dataset == "synthetic-images":
        out[SyntheticImagesConfig.SECTION] = SyntheticImagesConfig
    return out


def run_sections(dataset: str, backend: str) -> dict[str, type]:
    """:func:`visual_sections` for an image sequence, else
    :func:`graphslam.registry.planar_sections`."""
    from graphslam.registry import is_visual_dataset, planar_sections

    if is_visual_dataset(dataset):
        return visual_sections(dataset, backend)
    return planar_sections(dataset, backend)


def _toml_value(value) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, float) and value != value:
        return "nan"
    if isinstance(value, float) and abs(value) == float("inf"):
        return "inf" if value > 0 else "-inf"
    return json.dumps(value)  # strings, booleans, integers and floats read back as TOML


def run_config_file(config: dict) -> tuple[str, str]:
    """``(file name, text)`` of a run's config: TOML, or YAML where a setting is null
    (TOML has none; a YAML base config's ``known_gate_chi2_prob: null``, which ``run``
    takes, was written as TOML no run could read, and every run of the sweep failed)."""

    def holds_none(value) -> bool:
        if isinstance(value, dict):
            return any(holds_none(v) for v in value.values())
        if isinstance(value, list):
            return any(holds_none(v) for v in value)
        return value is None

    if holds_none(config):
        import yaml

        return "config.yaml", yaml.safe_dump(config, sort_keys=False, allow_unicode=True)
    return "config.toml", dump_toml(config)


def dump_toml(config: dict, prefix: tuple[str, ...] = ()) -> str:
    """A run's config as TOML text (tables and sub-tables of scalars and lists)."""
    lines, tables = [], []
    for key, value in config.items():
        if isinstance(value, dict):
            tables.append((key, value))
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    text = ""
    if prefix and (lines or not tables):
        text += f"[{'.'.join(prefix)}]\n"
    text += "".join(line + "\n" for line in lines)
    for key, value in tables:
        text += ("\n" if text else "") + dump_toml(value, prefix + (key,))
    return text


def _list(sweep: dict, cfg: ConfigFile, key: str, kind: type) -> list:
    value = sweep.get(key)
    line = cfg.line_of("sweep", key)
    if not isinstance(value, list) or not all(isinstance(v, kind) and not isinstance(v, bool) for v in value):
        raise ConfigError(
            f"[sweep] {key} must be a list of {kind.__name__}, got {quote(value)}", cfg.path, line
        )
    if not value:
        raise ConfigError(f"[sweep] {key} is empty: the grid has no run", cfg.path, line)
    _refuse_repeats(value, f"[sweep] {key}", cfg, line)
    return value


def _refuse_repeats(values: list, what: str, cfg: ConfigFile, line: int | None) -> None:
    """ConfigError naming the first value ``values`` holds twice: the grid runs it once,
    so a list of n values would give fewer than n runs without a word."""
    seen: list = []
    for v in values:
        key = (isinstance(v, bool), v)  # true == 1 in Python, not in TOML: [true, 1] is no repeat
        if key in seen:
            shown = _toml_value(v) if isinstance(v, bool) else repr(v)  # true, not Python's True
            raise ConfigError(f"{what} lists {shown} twice; each value is run once", cfg.path, line)
        seen.append(key)


def _datasets(sweep: dict, cfg: ConfigFile, path: Path) -> tuple[list[str], list[str]]:
    """``(datasets, entries)``: the ``dataset`` list as the runs are given it (built-in
    names as they are, paths read beside the sweep file as ``config`` is, made absolute:
    a run's command is the same from any working directory) and as the file lists it,
    each checked to exist before any run."""
    from graphslam.registry import is_builtin_dataset, no_such_dataset

    out, entries = [], _list(sweep, cfg, "dataset", str)
    for name in entries:
        if is_builtin_dataset(name):
            out.append(name)
            continue
        where = path.parent / name
        if not where.exists():
            raise ConfigError(
                f"[sweep] {no_such_dataset(repr(name))}; a path is read beside the sweep file ({where})",
                cfg.path,
                cfg.line_of("sweep", "dataset"),
            )
        out.append(str(where.absolute()))
    # two spellings of one file ("g.g2o", "./g.g2o", a link to it) are one dataset: its
    # runs would be made once, and the grid would have fewer runs than its lists say
    _refuse_repeats([dataset_key(d) for d in out], "[sweep] dataset", cfg, cfg.line_of("sweep", "dataset"))
    return out, entries


def _base_config(value, cfg: ConfigFile, path: Path) -> Path:
    """``[sweep] config``, read beside the sweep file; a value that names no file is
    refused at its line (it was taken as a path whatever it was: ``config = 5`` was
    "5: config file not found", ``config = ""`` the sweep's own folder)."""
    line = cfg.line_of("sweep", "config")
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(
            f"[sweep] config must name a config file (.toml, .yaml or .yml), got {quote(value)}",
            cfg.path,
            line,
        )
    where = path.parent / value
    if not where.is_file():
        what = "is a folder" if where.is_dir() else "is not a file" if where.exists() else "does not exist"
        raise ConfigError(
            f"[sweep] config {quote(value)} {what}; a path is read beside the sweep file ({where})",
            cfg.path,
            line,
        )
    return where


def _refuse_seeds_of_solves(seeds: tuple, datasets: list[str], backends: list[str], cfg: ConfigFile) -> None:
    """ConfigError when seeds are listed and a run of the grid is a pose-graph solve: it
    draws no random numbers, so each of its runs would fail on ``--seed`` (as ``graphslam
    run`` refuses it), after the sweep had started."""
    from graphslam.registry import is_pose_graph_run, is_visual_dataset, seed_draws_nothing

    if seeds == (None,):
        return
    for dataset, backend in itertools.product(datasets, backends):
        if is_pose_graph_run(dataset, backend):
            raise ConfigError(
                f"[sweep] seed: {backend} on {dataset} is a pose-graph solve, which draws no "
                "random numbers; sweep such files without seed (or in a sweep of their own)",
                cfg.path,
                cfg.line_of("sweep", "seed"),
            )
        # a 2-D landmark run refuses --seed as run does (each run failed, after the start)
        if not is_visual_dataset(dataset) and seed_draws_nothing(dataset, backend):
            raise ConfigError(
                f"[sweep] seed: {backend} on {dataset} draws no random numbers and the data is "
                "not simulated, so every seed would be the same run; sweep seeds over synthetic "
                "data or FastSLAM, or leave seed out",
                cfg.path,
                cfg.line_of("sweep", "seed"),
            )


#: The data's settings ``graphslam run --seed`` sets: the simulated worlds' generators
#: and the derived odometry's noise (the back ends' come from the table:
#: :func:`keys_seed_sets`).
DATA_KEYS_SEED_SETS = ("synthetic.seed", "synthetic_images.seed", "odometry_noise.seed")


def keys_seed_sets() -> set[str]:
    """Every ``section.seed`` that ``graphslam run --seed`` sets: the data's, and the
    ``seed`` of each back end that draws random numbers or whose run overrides take the
    seed (the visual iSAM2's RANSACs), read from the back-end table so that a new one is
    covered. A sweep with ``[sweep] seed`` hands ``--seed`` to every run, which overrides
    these whatever ``[sweep.set]`` says."""
    from graphslam.backend_table import TABLE, load

    keys = set(DATA_KEYS_SEED_SETS)
    for row in TABLE:
        for impl in (row.landmarks, row.images):
            if impl is not None and (impl.seeded or impl.run_overrides is not None):
                keys.add(f"{load(impl.config).SECTION}.seed")
    return keys


def _refuse_keys_seed_sets(seeds: tuple, keys: tuple, cfg: ConfigFile) -> None:
    """ConfigError when ``[sweep] seed`` is given and ``[sweep.set]`` sweeps a key that
    ``--seed`` sets: every run would get ``--seed``'s value, the swept one silently
    lost (tenth hostile pass: three runs labelled synthetic.seed 1, 2, 3, one result)."""
    if seeds == (None,):
        return
    set_by_seed = keys_seed_sets()
    for dotted in keys:
        if dotted in set_by_seed:
            raise ConfigError(
                f"[sweep.set] {dotted}: [sweep] seed gives every run --seed, which sets "
                f"{dotted}; sweep the seeds in one place ([sweep] seed, or {dotted} without it)",
                cfg.path,
                cfg.line_of("sweep", "set", *dotted.split(".")),
            )


def _seeds(sweep: dict, cfg: ConfigFile) -> tuple[int | None, ...]:
    value = sweep.get("seed")
    line = cfg.line_of("sweep", "seed")
    if value is None:
        return (None,)
    if isinstance(value, dict):
        if set(value) != {"from", "to"} or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in value.values()
        ):
            raise ConfigError(
                f"[sweep] seed must be a list or {{from = A, to = B}} with whole numbers, got {value!r}",
                cfg.path,
                line,
            )
        if value["to"] < value["from"]:
            raise ConfigError(
                f"[sweep] seed range {value['from']}..{value['to']} is empty: the grid has no run",
                cfg.path,
                line,
            )
        if value["to"] - value["from"] >= MAX_SEEDS:
            raise ConfigError(f"[sweep] seed range holds more than {MAX_SEEDS} seeds", cfg.path, line)
        seeds = tuple(range(value["from"], value["to"] + 1))
    else:
        seeds = tuple(_list(sweep, cfg, "seed", int))
    bad = next((s for s in seeds if not 0 <= s <= INT_LIMIT), None)
    if bad is not None:  # each run would fail on it, after the sweep had started
        raise ConfigError(
            f"[sweep] seed {bad} is outside 0 to 2**62 (what graphslam run --seed takes)", cfg.path, line
        )
    return seeds


def _grid_sections(datasets, backends) -> dict[str, type]:
    """Config classes by section name that some run of the grid reads."""
    sections: dict[str, type] = {}
    for d, b in itertools.product(datasets, backends):
        sections.update(run_sections(d, b))
    return sections


def _set_hint(key: str, sweep: dict, cfg: ConfigFile, path) -> str:
    """``"; ... [sweep.set] "mrclam.robot" = [...]"`` when a section these runs read has a
    setting named ``key`` (``robot = [1, 2]`` in [sweep] was refused naming the sweep's own
    keys only), else ``""``; nothing when the grid itself does not parse (that error comes next)."""
    try:
        sections = _grid_sections(_datasets(sweep, cfg, Path(path))[0], _list(sweep, cfg, "backend", str))
    except GraphSlamError:
        return ""
    hits = [f'"{name}.{key}"' for name, cls in sorted(sections.items()) if key in field_names(cls)]
    return f"; a section's setting is swept under [sweep.set]: {' or '.join(hits)} = [...]" if hits else ""


def _dotted(table: dict, prefix: str = "") -> dict:
    """``[sweep.set]`` with its sub-tables as dotted keys: TOML reads an unquoted
    ``ekf.association = [...]`` (and a ``[sweep.set.ekf]`` table) as a table ``ekf``,
    which was refused as "'ekf': not a section.key" with no line (hostile pass 22)."""
    out: dict = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and isinstance(key, str):
            out.update(_dotted(value, name + "."))
        else:
            out[name] = value
    return out


def _check_set(
    sweep: dict, cfg: ConfigFile, grid_sections: dict, base: dict | None = None
) -> tuple[tuple, tuple]:
    """``(keys, value lists)`` of ``[sweep.set]``, each value checked by its config class
    over the base config's section, and every combination of one section's swept values
    (a value fine with the defaults may not be with the base's, and two values fine alone
    may not be together: either failed every run it made, hostile pass 22)."""
    base = base or {}
    table = sweep.get("set", {})
    if not isinstance(table, dict):
        raise ConfigError("[sweep.set] must be a table", cfg.path, cfg.line_of("sweep", "set"))
    keys, values = [], []
    for dotted, options in table.items():
        line = cfg.line_of("sweep", "set", *dotted.split("."))
        section, _, key = dotted.partition(".")
        cls = grid_sections.get(section)
        if cls is None or not key:
            raise ConfigError(
                f"[sweep.set] {dotted!r}: not a section.key that these runs read "
                f"(sections: {', '.join(sorted(grid_sections))})",
                cfg.path,
                line,
            )
        if not isinstance(options, list) or not options:
            raise ConfigError(
                f"[sweep.set] {dotted} must be a non-empty list of values: the grid has no run",
                cfg.path,
                line,
            )
        _refuse_repeats(options, f"[sweep.set] {dotted}", cfg, line)
        for value in options:
            try:
                from_dict(cls, {**_section_of(base, section), key: value})
            except ConfigError as e:
                raise ConfigError(f"[sweep.set] {dotted} = {quote(value)}: {e}", cfg.path, line) from None
        keys.append(dotted)
        values.append(tuple(options))
    _check_combinations(keys, values, grid_sections, base, cfg)
    return tuple(keys), tuple(values)


def _check_base(base_cfg: ConfigFile, sections: dict, table) -> None:
    """Build every section the grid reads from the base config, with the first value of
    each key ``[sweep.set]`` sweeps in it: an error names the base file and line (every
    run failed instead, naming its own generated config.toml: hostile pass 22), or the
    swept key; :func:`_check_set` then checks every swept value."""
    swept: dict[str, dict] = {}
    for dotted, options in (table if isinstance(table, dict) else {}).items():
        if isinstance(dotted, str) and isinstance(options, list) and options:
            section, _, key = dotted.partition(".")
            swept.setdefault(section, {})[key] = options[0]
    for name, cls in sections.items():
        over = {k: v for k, v in swept.get(name, {}).items() if k in field_names(cls)}
        base_cfg.section(cls, overrides=over or None, flags={k: f"[sweep.set] {name}.{k}" for k in over})


def _section_of(base: dict, section: str) -> dict:
    table = base.get(section)
    return dict(table) if isinstance(table, dict) else {}


def _check_combinations(keys: list, values: list, grid_sections: dict, base: dict, cfg: ConfigFile) -> None:
    """ConfigError naming the first combination of one section's swept values (over the
    base's) that its config class refuses; the grid is capped (:func:`_check_size`)."""
    by_section: dict[str, list[int]] = {}
    for i, dotted in enumerate(keys):
        by_section.setdefault(dotted.partition(".")[0], []).append(i)
    for section, idx in by_section.items():
        if len(idx) < 2:
            continue
        for combo in itertools.islice(itertools.product(*(values[i] for i in idx)), MAX_RUNS):
            settings = {keys[i].partition(".")[2]: v for i, v in zip(idx, combo, strict=True)}
            try:
                from_dict(grid_sections[section], {**_section_of(base, section), **settings})
            except ConfigError as e:
                said = ", ".join(f"{keys[i]} = {quote(v)}" for i, v in zip(idx, combo, strict=True))
                raise ConfigError(
                    f"[sweep.set] {said} together: {e}", cfg.path, cfg.line_of("sweep", "set")
                ) from None


def _check_size(sweep: dict, cfg: ConfigFile, outer: int, values: tuple[tuple, ...]) -> None:
    """ConfigError when the grid (counted, not listed) exceeds its cap."""
    cap = sweep.get("max_runs", MAX_RUNS)
    if not isinstance(cap, int) or isinstance(cap, bool) or cap < 1:
        raise ConfigError(
            f"[sweep] max_runs must be a whole number >= 1, got {cap!r}",
            cfg.path,
            cfg.line_of("sweep", "max_runs"),
        )
    size = outer
    for v in values:
        size *= len(v)
    if size > cap:
        raise ConfigError(
            f"[sweep] the grid has {size} runs, above its cap of {cap}: shrink "
            f"the lists, or set [sweep] max_runs = {size} if you mean it",
            cfg.path,
            cfg.line_of("sweep"),
        )


def parse_sweep(path: str | Path) -> SweepSpec:
    """Read and check a sweep file (module doc); ConfigError with file and line."""
    from graphslam.registry import BACKENDS, VISUAL_BACKENDS, is_visual_dataset, read_config

    cfg = ConfigFile.read(path)
    for name in cfg.data:
        if name != "sweep":
            raise ConfigError(
                f"unknown table [{name}]; a sweep file has [sweep] and [sweep.set]",
                cfg.path,
                cfg.line_of(name),
            )
    sweep = cfg.data.get("sweep")
    if sweep is None:
        raise ConfigError("no [sweep] table", cfg.path)
    if isinstance(sweep, dict) and isinstance(sweep.get("set"), dict):
        sweep = {**sweep, "set": _dotted(sweep["set"])}
    for key in sweep:
        if key not in SWEEP_KEYS:
            hint = _set_hint(key, sweep, cfg, path)
            raise ConfigError(
                f"unknown key {key!r} in [sweep]; known: {', '.join(SWEEP_KEYS)}{hint}",
                cfg.path,
                cfg.line_of("sweep", key),
            )
    datasets, entries = _datasets(sweep, cfg, Path(path))
    backends = _list(sweep, cfg, "backend", str)
    visual = [name for name in datasets if is_visual_dataset(name)]
    for b in backends:
        if b not in BACKENDS:
            raise ConfigError(
                f"[sweep] unknown back end {b!r} (available: {', '.join(BACKENDS)})",
                cfg.path,
                cfg.line_of("sweep", "backend"),
            )
        if visual and b not in VISUAL_BACKENDS:
            raise ConfigError(
                f"[sweep] back end {b!r} does not run on the image sequence "
                f"{visual[0]!r} (available: {', '.join(VISUAL_BACKENDS)})",
                cfg.path,
                cfg.line_of("sweep", "backend"),
            )
    max_steps = sweep.get("max_steps")
    if max_steps is not None and (
        not isinstance(max_steps, int) or isinstance(max_steps, bool) or max_steps < 1
    ):
        raise ConfigError(
            f"[sweep] max_steps must be a whole number >= 1, got {max_steps!r}",
            cfg.path,
            cfg.line_of("sweep", "max_steps"),
        )
    nees = sweep.get("nees", all(d == "synthetic" for d in datasets))
    if not isinstance(nees, bool):
        raise ConfigError(
            f"[sweep] nees must be true or false, got {nees!r}", cfg.path, cfg.line_of("sweep", "nees")
        )
    notes = []
    if "nees" not in sweep and not nees and "synthetic" in datasets:
        notes.append(
            "[sweep] nees is unset, and off because not every dataset is the synthetic world: "
            "the synthetic runs score no NEES either; set nees = true for it"
        )
    if nees and visual:
        raise ConfigError(
            f"[sweep] nees = true, but {visual[0]!r} is an image sequence, whose "
            f"runs write no nees.csv: set nees = false",
            cfg.path,
            cfg.line_of("sweep", "nees"),
        )
    base = {}
    sections = _grid_sections(datasets, backends)
    if "config" in sweep:
        base_cfg = read_config(_base_config(sweep["config"], cfg, Path(path)))
        _check_base(base_cfg, sections, sweep.get("set"))
        base = dict(base_cfg.data)
    keys, values = _check_set(sweep, cfg, sections, base)
    seeds = _seeds(sweep, cfg)
    _refuse_seeds_of_solves(seeds, datasets, backends, cfg)
    _refuse_keys_seed_sets(seeds, keys, cfg)
    _check_size(sweep, cfg, len(datasets) * len(backends) * len(seeds), values)
    return SweepSpec(
        Path(path),
        tuple(datasets),
        tuple(backends),
        seeds,
        max_steps,
        nees,
        base,
        keys,
        values,
        tuple(entries),
        tuple(notes),
    )
