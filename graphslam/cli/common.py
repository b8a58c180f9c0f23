"""What every command shares: the sub-command registration and the options several
commands take, exit statuses, the summary-table formatting and the Rerun sink checks
(a viewer that cannot be used becomes a saved recording)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from slamcore.errors import GraphSlamError, InputError

#: Help of ``--topics`` (run, compare, localize): which topics of a ROS bag to read.
TOPICS_HELP = (
    "ROS bags: topics to read, e.g. image=/cam0/image_raw,camera_info=/cam0/"
    "camera_info,truth=/vicon/pose (default: the one topic of each kind; "
    "refused for other datasets)"
)

#: ``--rerun``: where the recording goes; the first (save) is the default.
RERUN_MODES = ("save", "spawn", "connect", "off")

EXIT_OK = 0
#: Some of the work failed; what succeeded is written (``compare``).
EXIT_FAILED = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def path_arg(text: str) -> Path:
    """argparse ``type`` of every path argument: an empty one is refused (an unset shell
    variable would otherwise name the current folder); a leading ``~`` is the home
    folder, as the shell would have made it (it does not after ``--out=``: a folder
    named ``~`` was written while the summary said ``~/...``)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (an unset shell variable?)")
    return Path(os.path.expanduser(text))


def file_out_arg(text: str) -> Path:
    """argparse ``type`` of an output that is one file (:func:`path_arg`): one ending in a
    slash names a folder, which ``Path`` forgets (``convert g.g2o x.g2o/`` wrote a file
    ``x.g2o``)."""
    from slamcore.files import names_a_folder

    if names_a_folder(text):
        raise argparse.ArgumentTypeError(f"{text} names a folder (it ends in a slash); give a file name")
    return path_arg(text)


def add_command(sub, name: str, func, *, help: str, description: str, epilog: str | None = None):
    """Register the sub-command ``graphslam NAME`` (``func(args)`` runs it; None for a
    command with sub-commands of its own) and return its parser. With an ``epilog``
    (tables, examples) the description and the epilog are printed as written."""
    layout: dict = {}
    if epilog is not None:
        layout = {"epilog": epilog, "formatter_class": argparse.RawDescriptionHelpFormatter}
    parser = sub.add_parser(name, help=help, description=description, **layout)
    if func is not None:
        parser.set_defaults(func=func)
    return parser


def add_choice_option(parser, flag: str, choices: tuple[str, ...], help: str) -> None:
    """An option taking one of ``choices``, the first the default."""
    parser.add_argument(flag, choices=choices, default=choices[0], help=help)


#: What ``--dataset`` of run and compare takes (one text: compare's named no landmark log).
DATASET_HELP = (
    "built-in dataset name, a landmark log (Victoria Park's format, TORO with BR lines, an "
    "MRCLAM folder), a pose-graph file, an image-sequence folder or a ROS bag (default: synthetic)"
)


def add_dataset_option(parser, help: str = DATASET_HELP) -> None:
    """``--dataset`` of run and compare: a name or a path, the synthetic world by default."""
    parser.add_argument("--dataset", default="synthetic", metavar="NAME|PATH", help=help)


def add_topics_option(parser, help: str = TOPICS_HELP) -> None:
    """``--topics ROLE=TOPIC,...``: the topics of a ROS bag to read."""
    parser.add_argument("--topics", default=None, metavar="ROLE=TOPIC,...", help=help)


#: Help of ``--intrinsics`` where it names an image sequence's camera (run, compare, localize).
INTRINSICS_HELP = (
    "camera intrinsics of a plain image folder, a TUM RGB-D folder or a ROS bag "
    "without its own (a file of 'fx fy cx cy', or the 3x3 K, optionally with "
    "distortion: see graphslam.sources.spatial.calibration); KITTI, EuRoC, a bag's "
    "camera_info and the synthetic sequence carry their own camera"
)

#: What ``run`` adds: the camera of a plain folder estimated from its photos.
INTRINSICS_ESTIMATE_HELP = (
    "; 'estimate' (a plain image folder, run only): the focal length and radial distortion "
    "(COLMAP's SIMPLE_RADIAL, principal point at the centre) estimated from the images by "
    "bundle adjustment; written to intrinsics.txt in the output folder"
)


def intrinsics_arg(text: str) -> Path | str:
    """argparse ``type`` of ``--intrinsics``: the word ``estimate`` as that ``str``
    (:data:`~graphslam.sources.spatial.calibration.ESTIMATE`), anything else a path
    (:func:`path_arg`; a file named ``estimate`` is ``./estimate``)."""
    return text if text == "estimate" else path_arg(text)


def refuse_intrinsics_estimate(intrinsics, command: str) -> None:
    """``--intrinsics estimate`` outside ``run``: one line naming what to pass instead."""
    if isinstance(intrinsics, str) and intrinsics == "estimate":
        raise GraphSlamError(
            f"--intrinsics estimate: graphslam {command} does not estimate a camera; pass the "
            "intrinsics.txt that 'graphslam run --intrinsics estimate' wrote in its output folder"
        )


def check_out_keeps_the_camera(dataset: str, out: Path, intrinsics=None) -> None:
    """Refuse, before any work, an ``--out`` that holds the data set's own camera file
    (a photo folder run into itself): every command clears the outputs it will not write
    there, ``intrinsics.txt`` among them, and ``--intrinsics estimate`` writes its own,
    so the folder's calibration would be lost; an estimate written into the photo
    folder would be read as its calibration by the next run on it."""
    from graphslam import registry
    from graphslam.outputs.writers import FOLDER_OUTPUT_NAMES
    from graphslam.sources.spatial.calibration import is_estimate
    from slamcore.errors import ConfigError
    from slamcore.files import check_not_inputs

    check_not_inputs(
        [("the output (in --out)", Path(out) / name) for name in FOLDER_OUTPUT_NAMES],
        {"--dataset's camera file": registry.camera_file(dataset)},
    )
    if is_estimate(intrinsics) and Path(dataset).is_dir() and Path(out).resolve() == Path(dataset).resolve():
        raise ConfigError(
            f"--intrinsics estimate writes intrinsics.txt in --out, here the image folder {dataset} "
            "itself, where the next run on the folder would read it as the folder's calibration; "
            "choose --out in another folder"
        )


def add_intrinsics_option(parser, help: str = INTRINSICS_HELP) -> None:
    """``--intrinsics FILE``: the camera of an image folder (``estimate``: see
    :func:`intrinsics_arg`; only ``run`` takes it, the others refuse it in one line)."""
    parser.add_argument("--intrinsics", type=intrinsics_arg, default=None, metavar="FILE", help=help)


def add_frames_option(parser, help: str) -> None:
    """``--frames START:STOP[:STEP]``: a Python slice of an image sequence."""
    parser.add_argument("--frames", default=None, metavar="START:STOP[:STEP]", help=help)


def add_out_dir_option(parser, help: str = "output folder", *, required: bool = False, default=None) -> None:
    """``--out``: the output folder."""
    parser.add_argument("--out", type=path_arg, required=required, default=default, help=help)


def add_config_option(parser, help: str, metavar: str | None = None) -> None:
    """``--config``: a TOML or YAML configuration file."""
    parser.add_argument("--config", type=path_arg, default=None, metavar=metavar, help=help)


def add_max_steps_option(parser) -> None:
    """``--max-steps N`` of run and compare."""
    parser.add_argument("--max-steps", type=int, default=None, metavar="N", help="stop after N frames")


def add_rerun_options(parser, help: str, url_help: str = "viewer gRPC URL for --rerun connect") -> None:
    """``--rerun`` (:data:`RERUN_MODES`) and ``--rerun-url``, checked by
    :func:`check_rerun_flags`."""
    add_choice_option(parser, "--rerun", RERUN_MODES, help)
    parser.add_argument("--rerun-url", default=None, help=url_help)


def add_quiet_option(parser) -> None:
    """``--quiet``: no progress bar."""
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def robot_arg(text: str) -> int | str:
    """``--robot``: a robot number (1-5 in the MRCLAM sets) or ``all``."""
    if text == "all":
        return text
    if text.isascii() and text.isdigit() and 1 <= int(text) <= 5:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected a robot number 1-5 or all, got {text[:40]!r}")


def seed_arg(text: str) -> int:
    """``--seed``: a whole number from 0 to 2**62 (:data:`slamcore.config.INT_LIMIT`),
    said as the flag's error rather than as the config field it ends up in."""
    from slamcore.config import INT_LIMIT

    return _whole_number(text, INT_LIMIT, "2**62")


def kmeans_seed_arg(text: str) -> int:
    """``vocab train --seed``: a whole number from 0 to 2**32 - 1, what scikit-learn's
    k-means takes as its ``random_state`` (:data:`loopclosure.vocabulary_training.KMEANS_SEED_MAX`)."""
    from loopclosure.vocabulary_training import KMEANS_SEED_MAX

    return _whole_number(text, KMEANS_SEED_MAX, "2**32 - 1")


def _whole_number(text: str, limit: int, limit_text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text[:40]!r}") from None
    if not 0 <= value <= limit:
        raise argparse.ArgumentTypeError(f"expected a whole number from 0 to {limit_text}, got {value}")
    return value


def add_robot_option(parser, help: str) -> None:
    """``--robot N|all`` of run and compare (:func:`robot_arg`)."""
    parser.add_argument("--robot", type=robot_arg, default=None, metavar="N|all", help=help)


def summary_table(rows: list[tuple[str, object]]) -> str:
    """``(label, value)`` rows as an indented two-column table."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def counts_row(label: str, counts: dict, *keys: str) -> tuple[str, str]:
    """A summary row of several counts, ``"a / b / c"`` (``counts[key]`` of each key);
    the label names them in the same way."""
    return label, " / ".join(str(counts[k]) for k in keys)


def fmt(value, spec: str) -> str:
    """``value`` formatted with ``spec``, or "n/a" when it is None."""
    return "n/a" if value is None else format(value, spec)


def recoveries_text(recoveries: dict[str, int]) -> str:
    """The non-zero numerical recovery counts, e.g. ``"damped_update 3, noise_floor 1"``."""
    return ", ".join(f"{k} {v}" for k, v in recoveries.items() if v)


def report_outputs(summary: str, out_dir: Path, paths: dict, interrupted: bool, cut=None, writes=None) -> int:
    """Print a run's summary table and where its outputs went; the exit status.

    ``cut``: the :class:`~graphslam.pipelines.common.FrameUnreadable` (or
    ``BackendFailed``) that stopped the run, raised again once its estimate so far is
    written and listed (exit 2, its file). ``writes``: the run's
    :class:`~graphslam.outputs.writers.OutputWrites`, whose refused files are named
    here; its caller checks it once every output was tried.
    """
    from graphslam.outputs.writers import OutputWrites

    print(summary)
    print((writes or OutputWrites(out_dir)).outputs_line(paths.values()))
    if cut is not None and not isinstance(cut, InputError):  # the back end failed
        raise GraphSlamError(
            f"{cut}; the run stopped at frame {cut.frame}: {out_dir}/ holds what it estimated "
            "from the frames before it"
        )
    if cut is not None:
        raise InputError(
            f"{cut.reason}; the run stopped at this frame: {out_dir}/ holds what it "
            f"estimated from the frames before it",
            cut.path,
            cut.line,
        )
    if interrupted:
        from graphslam.pipelines.common import active_guard

        guard = active_guard()
        name = "" if guard is None else f" ({guard.signal_name})"
        print(f"graphslam: interrupted{name}; wrote the estimate so far", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK


#: Longest error line printed: a full path (PATH_MAX 4096) and a sentence fit;
#: a message that quotes a huge token whole (a bug) cannot flood stderr.
MAX_ERROR_CHARS = 8000


def one_line(message: str) -> str:
    """``message`` on one line and at most :data:`MAX_ERROR_CHARS` characters."""
    message = " ".join(message.splitlines())
    if len(message) > MAX_ERROR_CHARS:
        message = f"{message[:MAX_ERROR_CHARS]}... ({len(message)} characters)"
    return message


def warn(message: str) -> None:
    """One ``graphslam: warning:`` line on stderr (one, though a file name it quotes holds
    a newline: hostile pass 18)."""
    print(f"graphslam: warning: {one_line(message)}", file=sys.stderr, flush=True)


def warn_run_doubts(doubts, said=()) -> None:
    """Each of one run's ``doubts`` (``metrics.warnings``) not in ``said`` (the reader's,
    said at the start) as a warning on stderr (:func:`warn_doubts` is compare's): every
    run command's doubts go there, not into the summary on stdout, which may go to a
    file (hostile pass 18)."""
    for doubt in doubts or ():
        if doubt not in said:
            warn(doubt)


def warn_shadowed_dataset(spec, flag: str = "--dataset") -> None:
    """A warning when ``spec`` names both a built-in data set and a file here
    (:func:`graphslam.registry.shadowed_dataset_name`)."""
    from graphslam import registry

    doubt = registry.shadowed_dataset_name(spec)
    if doubt is not None:
        warn(f"{flag} {doubt}")


def invocation(args) -> dict:
    """Where and with what a command ran: its command line as typed (relative paths and
    all), the working directory they are read from, its ``--config`` as typed and
    resolved, the interpreter, the versions of the
    toolkit and its libraries and the digest of the toolkit's source
    (:func:`graphslam.pipelines.provenance.code_identity`). Without them an output could not be
    made again from another folder or told from another version's (fifteenth hostile
    pass)."""
    from graphslam.pipelines.provenance import code_identity

    try:
        cwd: str | None = os.getcwd()
    except OSError:  # the folder was removed under the command: nothing to name
        cwd = None
    config = getattr(args, "config", None)
    return {
        "command": list(getattr(args, "command_line", None) or []),
        "cwd": cwd,
        "config_file": None if config is None else str(config),
        "config_file_resolved": None if config is None else os.path.realpath(config),
        "python_executable": sys.executable,
        **code_identity(),
    }


def provenance(args, config) -> dict:
    """What a run's metrics.json records of how it was asked for: :func:`invocation`, the
    config file (path as typed and resolved, SHA-256 of its bytes) and every section's
    settings as built (thirteenth hostile pass: a run's outputs said nothing of its
    settings, so it could not be made again from them)."""
    import hashlib

    if config.path is not None and config.sha256 is not None:
        try:
            now = hashlib.sha256(Path(config.path).read_bytes()).hexdigest()
        except OSError:  # gone since it was read: the settings below still say what ran
            now = config.sha256
        if now != config.sha256:
            warn(
                f"--config {config.path} changed during the run: metrics.json gives the SHA-256 "
                "of the file as it was read, and the settings that ran"
            )
    return {
        **invocation(args),
        "config_file": None if config.path is None else str(config.path),
        "config_file_resolved": None if config.path is None else os.path.realpath(config.path),
        "config_sha256": config.sha256,
        "settings": dict(config.settings),
        # the file's settings that did nothing, as said on stderr (GATES and marks so far)
        "did_nothing": config.inert_lines(),
    }


def warn_unread_sections(config, path, command: str) -> None:
    """A warning naming the ``--config`` sections ``command`` never read (a file shared
    with other back ends or commands): their settings did nothing and were not checked
    (eleventh hostile pass: ``[ekf] zzz = 1`` under the default back end ran silently);
    and one for each group of settings the others' modes left unread
    (:meth:`slamcore.config.ConfigFile.inert_lines`)."""
    unread = config.unread_sections()
    if unread:
        warn(
            f"--config {path}: {', '.join(f'[{s}]' for s in unread)} not read by {command}; "
            "those settings did nothing and were not checked"
        )
    for line in config.inert_lines():  # read, but left unread by the others' modes
        warn(line)


def warn_doubts(doubts: dict[str, list[str] | None]) -> None:
    """``graphslam: warning:`` lines for what each back end's metrics say makes its
    estimate doubtful (``{backend: warnings}``, as ``run`` says its own): a doubt every
    back end of several shares (the input's) once, each other one with its back end."""
    lists = [list(ws or ()) for ws in doubts.values()]
    shared = [w for w in lists[0] if all(w in ws for ws in lists[1:])] if len(lists) > 1 else []
    for w in shared:
        warn(w)
    for name, ws in doubts.items():
        for w in ws or ():
            if w not in shared:
                warn(f"{name}: {w}")


def check_rerun_flags(args) -> None:
    """Refuse Rerun flags that would do nothing, and a malformed ``--rerun-url``,
    before any work."""
    from graphslam.visualisation.recording import check_recording_path, parse_viewer_url
    from slamcore.errors import ConfigError

    if args.rerun == "save" and getattr(args, "out", None) is not None:
        check_recording_path(args.out, "--out")
    if args.rerun_url is not None:
        if args.rerun != "connect":
            raise ConfigError("--rerun-url applies to --rerun connect only")
        parse_viewer_url(args.rerun_url)
    every = getattr(args, "rerun_every", None)
    if every is not None:
        if args.rerun == "off":
            raise ConfigError("--rerun-every applies only when a recording is made (not with --rerun off)")
        if every < 1:
            raise ConfigError("--rerun-every must be at least 1")


def rerun_sink(mode: str, url: str | None, file_name: str) -> str:
    """The stream a run will use: ``mode``, or "save" (after one warning line)
    when the viewer to spawn or connect to cannot be used."""
    from graphslam.visualisation.recording import sink_problem

    problem = sink_problem(mode, url)
    if problem is None:
        return mode
    warn(f"{problem}; saving {file_name} in the output folder instead")
    return "save"


#: Positional arguments holding paths, as ``--help`` names them (by command, dest).
_POSITIONAL_PATHS: dict[tuple[str | None, str], str] = {
    ("eval", "ground_truth"): "GT",
    ("eval", "estimates"): "EST",
    ("convert", "input"): "IN",
    ("convert", "output"): "OUT",
    ("loops", "images_dir"): "IMAGES_DIR",
    ("vocab", "images"): "IMAGES",
    ("sweep", "sweep_file"): "SWEEP.toml",
    ("info", "bag"): "BAG",
}
#: Options given as text that may be a path (a data set name or its folder).
_TEXT_PATHS = ("dataset", "images")


def check_path_arguments(args) -> None:
    """Refuse, before any work, a path argument with a name over the file-system limit,
    naming the option (the system's ENAMETOOLONG names neither, and may come after
    minutes of work)."""
    from slamcore.files import check_name_lengths

    try:  # every relative path, and a sweep's runs, start from it
        os.getcwd()
    except FileNotFoundError:
        raise GraphSlamError(
            "the working folder was deleted (a shell still in it): cd to a folder that exists"
        ) from None
    command = getattr(args, "command", None)
    for dest, value in vars(args).items():
        values = value if isinstance(value, list) else [value]
        for v in values:
            if isinstance(v, Path) or (dest in _TEXT_PATHS and isinstance(v, str)):
                flag = _POSITIONAL_PATHS.get((command, dest), "--" + dest.replace("_", "-"))
                check_name_lengths(v, flag)
