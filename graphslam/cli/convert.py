"""``graphslam convert IN OUT``: a pose graph from one file format to the other."""

from __future__ import annotations

import argparse
import dataclasses

from graphslam.cli.common import add_choice_option, add_command, file_out_arg, path_arg
from slamcore.errors import ConfigError

FORMAT_OF_SUFFIX = {".g2o": "g2o", ".graph": "toro"}

#: ``--toro-noise`` and ``--information-fix``: posegraph_files.TORO_NOISE and
#: INFORMATION_FIX written out (building the parser imports no numpy), the first the default.
TORO_NOISE = ("auto", "information", "sqrt_information")
INFORMATION_FIX = ("nearest", "isotropic", "refuse")
TORO_NOISE_HELP = (
    "how TORO edge numbers are read and written: information (the "
    "format), sqrt_information (files written by iSAM), or auto "
    "(default: read as sqrt_information for the files known to hold it, such as "
    "gtsam's sphere2500.txt, said on stderr, else information; written as information)"
)
INFORMATION_FIX_HELP = (
    "an information matrix that is not positive definite is written as "
    "the nearest positive-definite one (default), as SE-Sync's isotropic "
    "weights, or refused"
)


def register(sub) -> None:
    p = add_command(
        sub,
        "convert",
        cmd_convert,
        help="convert a pose graph between g2o and TORO (2-D and 3-D)",
        description="Read a g2o or TORO pose graph (2-D or 3-D) and write it in the format "
        "that OUT's extension names (.g2o or .graph, unless --to), same dimension, "
        "numbers unchanged (3-D rotations re-expressed: quaternion <-> roll pitch "
        "yaw). g2o has no EQUIV lines: converting TORO to g2o drops them and says "
        "so.",
    )
    p.add_argument("input", type=path_arg, metavar="IN")
    p.add_argument("output", type=file_out_arg, metavar="OUT")
    p.add_argument(
        "--to", choices=("g2o", "toro"), default=None, help="output format (default: from OUT's extension)"
    )
    add_choice_option(p, "--toro-noise", TORO_NOISE, TORO_NOISE_HELP)
    add_choice_option(p, "--information-fix", INFORMATION_FIX, INFORMATION_FIX_HELP)


def cmd_convert(args: argparse.Namespace) -> int:
    from graphslam import registry
    from graphslam.cli.common import warn, warn_shadowed_dataset
    from graphslam.outputs.posegraph import convert, write_pose_graph
    from graphslam.sources.planar.posegraph import self_edges_note
    from slamcore.files import check_not_inputs, check_output_file

    fmt = args.to or FORMAT_OF_SUFFIX.get(args.output.suffix.lower())
    if fmt is None:
        raise ConfigError(
            f"cannot tell the output format from {args.output.name!r}: "
            "name it .g2o or .graph, or pass --to g2o|toro"
        )
    if args.output.is_dir():
        raise ConfigError("is a folder, not a file", args.output)
    check_output_file(args.output, "OUT")  # refused now, not after reading the graph
    check_not_inputs([("OUT", args.output)], {"IN": args.input})
    warn_shadowed_dataset(args.input, "IN")
    graph = registry.load_pose_graph(args.input, args.toro_noise, args.information_fix)
    converted, notes = convert(graph, fmt)
    notes[:0] = graph.warnings  # the reader's doubts: the output carries them on
    if graph.n_information_fixed:  # the numbers are no longer the file's: say so
        notes.append(
            f"{graph.n_information_fixed} edges' information matrices were not "
            f"positive definite: written as replaced ({graph.information_fix}; "
            "--information-fix refuse keeps the refusal)"
        )
    if graph.noise_note:
        notes.append(f"edge numbers read as {graph.noise_note}")
    self_edges = self_edges_note(graph)
    if self_edges:  # not written: the output holds every other edge, numbers unchanged
        notes.append(self_edges)
    if fmt == "toro":
        # auto writes information, what the format says and every reader takes: written
        # as read, sphere2500's square roots came back as information from the second
        # read on (only the file itself is known to hold them), its weights changed unsaid
        noise = "information" if args.toro_noise == "auto" else args.toro_noise
        if graph.noise == "sqrt_information" and noise == "information":
            notes.append(
                "the edges' square-root numbers are written as information, as TORO readers "
                "take them (--toro-noise sqrt_information writes square roots)"
            )
        converted = dataclasses.replace(converted, noise=noise)
    elif args.toro_noise != "auto" and graph.format != "toro":
        notes.append(f"--toro-noise {args.toro_noise} did nothing: it acts only on TORO files")
    for note in notes:
        warn(note)
    try:
        args.output.parent.mkdir(parents=True, exist_ok=True)  # as every --out makes its folder
        write_pose_graph(args.output, converted)
    except OSError as exc:
        raise ConfigError(f"cannot write: {exc.strerror or exc}", args.output) from None
    print(
        f"{args.input} ({graph.dim}-D {graph.format}, {graph.n_poses} poses, "
        f"{graph.n_edges} edges) -> {args.output} ({fmt})"
    )
    return 0
