"""Every option of ``graphslam run``, ``compare``, ``loops`` and ``vocab train`` has a
row here that shows its effect (a quick run with and without it differs) or its
refusal (exit 2, one line).

The options are read from the argparse parser itself, so an option added
without a row fails :func:`test_every_option_has_a_row`. Inputs are small: the
2-D synthetic world for 10 steps, 5 frames of the synthetic image sequence,
a few KITTI 07 frames and the 10 slambook2 desk images.
"""

from __future__ import annotations

import argparse
import io
import json
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from graphslam.cli.main import build_parser, main
from tests.conftest import SHARED_DATA

KITTI07 = SHARED_DATA / "kitti07"
DESK = SHARED_DATA / "slambook2_desk" / "images"

RUN_2D = ["run", "--max-steps", "10", "--rerun", "off", "--quiet"]
RUN_IMAGES = ["run", "--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "5",
              "--rerun", "off", "--quiet"]
COMPARE = ["compare", "--max-steps", "10", "--backends", "isam2", "ekf", "--in-process",
           "--rerun", "off"]


# --------------------------------------------------------------------------- the parser

def _subcommands(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _subcommands(sub, f"{prefix}{name} ")
            return
    yield prefix.strip(), parser


def command_options() -> set[str]:
    """``"run --seed"``-style keys of every option of the four commands."""
    keys = set()
    for command, parser in _subcommands(build_parser()):
        if command in ("run", "compare", "loops", "vocab train"):
            for action in parser._actions:
                if action.option_strings:
                    keys.add(f"{command} {max(action.option_strings, key=len)}")
    return keys


# --------------------------------------------------------------------------- running

@dataclass
class Result:
    rc: int
    out: str
    err: str
    files: dict[str, bytes] = field(default_factory=dict)

    def text(self, name: str) -> str:
        return self.files[name].decode()

    def metrics(self) -> dict:
        return json.loads(self.files["metrics.json"])


class _Tty(io.StringIO):
    def isatty(self) -> bool:  # progress bars draw only on a terminal
        return True


class Cli:
    """Runs ``graphslam`` in this process; each call gets its own output folder."""

    def __init__(self, tmp_path: Path, capsys, monkeypatch):
        self.tmp = tmp_path
        self.capsys = capsys
        self.monkeypatch = monkeypatch
        self.n = 0

    def path(self, name: str) -> Path:
        return self.tmp / name

    def __call__(self, *argv: str, tty: bool = False, out: bool = True) -> Result:
        self.n += 1
        folder = self.tmp / f"out{self.n}"
        args = list(argv)
        if out and args[0] in ("run", "compare") and "--out" not in args:
            args += ["--out", str(folder)]
        if tty:
            with self.monkeypatch.context() as m:
                fake = _Tty()
                m.setattr("sys.stderr", fake)
                rc = main(args)
                err = fake.getvalue()
            out_text = self.capsys.readouterr().out
        else:
            rc = main(args)
            cap = self.capsys.readouterr()
            out_text, err = cap.out, cap.err
        files = {p.name: p.read_bytes() for p in folder.iterdir()} if folder.is_dir() else {}
        return Result(rc, out_text, err, files)


def refused(res: Result, fragment: str) -> None:
    assert res.rc == 2, res.err
    lines = res.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("graphslam: error:"), res.err
    assert fragment in lines[0], lines[0]


def differ(a: Result, b: Result, name: str = "trajectory.tum") -> None:
    assert a.rc == 0 and b.rc == 0, a.err + b.err
    assert a.files[name] != b.files[name]


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _square_graph(cli: Cli) -> Path:
    from tests.graphslam.cli.test_run_options import _square_graph as square

    return square(cli.tmp)[0]


def _truth_of_square(cli: Cli) -> Path:
    import math

    from tests.graphslam.cli.test_run_options import _square_graph as square

    _, truth = square(cli.tmp)
    gt = cli.path("gt.tum")
    gt.write_text("".join(f"{k} {x} {y} 0 0 0 {math.sin(t / 2)} {math.cos(t / 2)}\n"
                          for k, (x, y, t) in enumerate(truth)))
    return gt


def _config(cli: Cli, text: str) -> Path:
    p = cli.path(f"c{abs(hash(text))}.toml")
    p.write_text(text)
    return p


def _kitti_bare(cli: Cli) -> Path:
    """KITTI 07 without its poses (links), for derived odometry from --ground-truth."""
    folder = cli.path("kitti_bare")
    if not folder.exists():
        folder.mkdir()
        for name in ("image_0", "calib.txt", "times.txt"):
            (folder / name).symlink_to(KITTI07 / name)
    return folder


@pytest.fixture(scope="module")
def vocab_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("vocab") / "desk.voc"
    assert main(["vocab", "train", str(DESK), "--words", "100", "--out", str(out),
                 "--quiet"]) == 0
    return out


# --------------------------------------------------------------------------- the table

ROWS: dict[str, Callable] = {}


def row(*keys: str):
    def register(fn):
        for key in keys:
            ROWS[key] = fn
        return fn
    return register


@row("run --help", "compare --help", "loops --help", "vocab train --help")
def _help(cli, key):
    command = key.rsplit(" ", 1)[0].split()
    with pytest.raises(SystemExit) as e:
        main([*command, "--help"])
    assert e.value.code == 0
    assert "usage: graphslam" in cli.capsys.readouterr().out


@row("run --dataset")
def _run_dataset(cli, key):
    differ(cli(*RUN_2D), cli(*RUN_2D, "--dataset", str(_square_graph(cli))))


def _two_camera_bag(cli: Cli) -> Path:
    """The first KITTI 07 frames as a ROS 1 bag with two cameras (tests/bags.py)."""
    pytest.importorskip("rosbags")
    from tests.bags import write_kitti_bag

    bag = cli.path("two.bag")
    return bag if bag.exists() else write_kitti_bag(bag, "ros1", second_camera=True)


@row("run --topics", "compare --topics", "loops --topics")
def _topics(cli, key):
    bag = str(_two_camera_bag(cli))
    if key.startswith("loops"):
        loops = ["loops", bag, "--words", "10", "--quiet", "--out", str(cli.path("l.csv"))]
        assert cli(*loops, "--topics", "image=/cam1/image_raw").rc == 0
        refused(cli(*loops), "2 image topics (/cam0/image_raw, /cam1/image_raw)")
        refused(cli("loops", str(DESK), "--out", str(cli.path("l.csv")), "--topics", "image=/x"),
                "--topics applies to ROS bags only")
        return
    # 5 frames: too few for the camera alone to start a map; odometry from the bag's truth
    if key.startswith("run"):
        base, name = ["run", "--dataset", bag, "--max-steps", "5", "--rerun", "off",
                      "--odometry", "derived"], "trajectory.tum"
    else:
        base, name = ["compare", "--max-steps", "5", "--dataset", bag, "--backends", "isam2",
                      "--in-process", "--rerun", "off", "--odometry", "derived"], "compare.json"
    a, b = cli(*base, "--topics", "image=/cam0/image_raw"), cli(*base, "--topics", "image=/cam1/image_raw")
    differ(a, b, name)
    assert "camera_info: /cam1/camera_info" in b.out + b.text(name)  # its camera's own
    refused(cli(*base), "2 image topics (/cam0/image_raw, /cam1/image_raw)")
    refused(cli(*(RUN_2D if key.startswith("run") else COMPARE), "--topics", "image=/x"),
            "--topics applies to ROS bags only")


@row("run --intrinsics", "compare --intrinsics")
def _intrinsics(cli, key):
    photos = SHARED_DATA / "lund_door" / "images"  # photos without a camera file
    if not photos.is_dir():
        pytest.skip("Lund door photos missing")
    f1, f2 = cli.path("f1.txt"), cli.path("f2.txt")
    f1.write_text("2435.38 2435.38 648 968\n")
    f2.write_text("2200 2200 648 968\n")
    if key.startswith("run"):
        base, name = ["run", "--dataset", str(photos), "--rerun", "off", "--quiet"], "trajectory.tum"
    else:
        base, name = ["compare", "--dataset", str(photos), "--backends", "isam2", "--in-process",
                      "--rerun", "off"], "compare.json"
    differ(cli(*base, "--intrinsics", str(f1)), cli(*base, "--intrinsics", str(f2)), name)
    refused(cli(*base), "no intrinsics: pass --intrinsics FILE")
    # run's --intrinsics estimate: test_photo_folders.py's test_lund_door_camera_estimated_from_its_photos
    # (the camera estimated, used and written; a second estimate here cost half a minute)
    if not key.startswith("run"):
        refused(cli(*base, "--intrinsics", "estimate"), "graphslam compare does not estimate a camera")
    refused(cli(*(RUN_2D if key.startswith("run") else COMPARE), "--intrinsics", str(f1)),
            "--intrinsics applies to image sequences only")


@row("run --backend")
def _run_backend(cli, key):
    differ(cli(*RUN_2D), cli(*RUN_2D, "--backend", "ekf"))


@row("run --seed")
def _run_seed(cli, key):
    differ(cli(*RUN_2D), cli(*RUN_2D, "--seed", "7"))
    graph = str(_square_graph(cli))
    # recorded data: only FastSLAM's particles draw random numbers (on a log with
    # sightings: until one weighs them, its trajectory is the odometry whatever the seed)
    particles = [*RUN_2D, "--dataset", str(SHARED_DATA / "mrclam6"), "--max-steps", "200",
                 "--backend", "fastslam1"]
    differ(cli(*particles), cli(*particles, "--seed", "7"))
    refused(cli(*RUN_2D, "--dataset", graph, "--seed", "7"), "--seed")


@row("run --robot")
def _run_robot(cli, key):
    mrclam = str(SHARED_DATA / "mrclam6")
    one, two = cli(*RUN_2D, "--dataset", mrclam), cli(*RUN_2D, "--dataset", mrclam, "--robot", "2")
    assert one.metrics()["dataset"] == "mrclam6-robot1"
    assert two.metrics()["dataset"] == "mrclam6-robot2"
    differ(one, two)
    refused(cli(*RUN_2D, "--robot", "2"), "--robot applies to MRCLAM folders only")


@row("run --init")
def _run_init(cli, key):
    graph = str(_square_graph(cli))
    batch = [*RUN_2D, "--dataset", graph, "--backend", "batch"]
    lago, odometry = cli(*batch), cli(*batch, "--init", "odometry")
    assert lago.metrics()["init"] == "lago" and odometry.metrics()["init"] == "odometry"
    assert lago.metrics()["initial_cost"] != odometry.metrics()["initial_cost"]
    refused(cli(*RUN_2D, "--init", "lago"), "pose-graph files only")
    refused(cli(*batch, "--init", "chordal"), "3-D graphs")


@row("run --out")
def _run_out(cli, key):
    target = cli.path("here")
    assert cli(*RUN_2D, "--out", str(target)).rc == 0
    assert (target / "trajectory.tum").is_file()


@row("run --write-bag")
def _run_write_bag(cli, key):
    pytest.importorskip("rosbags")
    target = cli.path("bagged")
    assert cli(*RUN_2D, "--out", str(target), "--write-bag").rc == 0
    assert (target / "trajectory.bag").stat().st_size > 0
    assert cli(*RUN_2D, "--out", str(target)).rc == 0  # without it: no bag (none stale)
    assert not (target / "trajectory.bag").exists()


@row("run --config")
def _run_config(cli, key):
    differ(cli(*RUN_2D), cli(*RUN_2D, "--config", str(_config(cli, "[synthetic]\nseed = 5\n"))))


@row("run --max-steps")
def _run_max_steps(cli, key):
    differ(cli(*RUN_2D), cli(*RUN_2D, "--max-steps", "5"))
    refused(cli(*RUN_2D, "--max-steps", "0"), "--max-steps")


@row("run --ground-truth")
def _run_ground_truth(cli, key):
    graph = str(_square_graph(cli))
    plain = cli(*RUN_2D, "--dataset", graph)
    scored = cli(*RUN_2D, "--dataset", graph, "--ground-truth", str(_truth_of_square(cli)))
    assert plain.metrics()["ate_rmse_m"] is None and scored.metrics()["ate_rmse_m"] is not None
    assert "ground_truth.tum" in scored.files and "ground_truth.tum" not in plain.files


@row("compare --ground-truth")
def _compare_ground_truth(cli, key):
    model = SHARED_DATA / "lund_door" / "colmap_ground_truth"
    if not (model / "images.txt").is_file():
        pytest.skip("Lund door COLMAP model missing")
    base = ["compare", "--dataset", str(SHARED_DATA / "lund_door" / "images"), "--intrinsics",
            str(model / "cameras.txt"), "--odometry", "none", "--backends", "isam2", "--in-process",
            "--rerun", "off"]
    plain = json.loads(cli(*base).files["compare.json"])["runs"][0]
    scored = json.loads(cli(*base, "--ground-truth", str(model / "images.txt")).files["compare.json"])["runs"][0]
    assert plain["ate_rmse_m"] is None and scored["ate_rmse_m"] is not None
    refused(cli(*COMPARE, "--ground-truth", str(model / "images.txt")),
            "--ground-truth applies to image sequences only")


@row("run --no-polish")
def _run_no_polish(cli, key):
    polished = cli(*RUN_2D, "--max-steps", "40")
    raw = cli(*RUN_2D, "--max-steps", "40", "--no-polish")
    assert polished.metrics()["final_error"] != raw.metrics()["final_error"]
    refused(cli(*RUN_2D, "--backend", "ekf", "--no-polish"), "isam2 back end only")


@row("run --rerun")
def _run_rerun(cli, key):
    saved = cli(*RUN_2D[:-3], "--quiet")  # default: save
    assert "run.rrd" in saved.files and "run.rrd" not in cli(*RUN_2D).files


@row("run --rerun-url", "compare --rerun-url")
def _rerun_url(cli, key):
    base = RUN_2D[:-3] if key.startswith("run") else COMPARE[:-2]
    url = f"rerun+http://127.0.0.1:{_closed_port()}/proxy"
    res = cli(*base, "--rerun", "connect", "--rerun-url", url)
    assert res.rc == 0 and url in res.err and res.err.startswith("graphslam: warning:")
    refused(cli(*base, "--rerun-url", url), "--rerun connect only")


@row("run --rerun-every")
def _run_rerun_every(cli, key):
    # A recording's size depends on Rerun's batching (timing), so count the whole-
    # estimate snapshots the recorder logs instead. 10 steps: the default logs one
    # every step (max(1, 10 // 50)), every 5th step gives 2 + the final one.
    from graphslam.visualisation.planar import PlanarLog

    calls = []
    real = PlanarLog.log_estimate
    cli.monkeypatch.setattr(PlanarLog, "log_estimate",
                            lambda self, *a, **kw: calls.append(1) or real(self, *a, **kw))
    base = RUN_2D[:-3]
    cli(*base, "--rerun-every", "5")
    sparse, calls[:] = len(calls), []
    cli(*base)
    assert (sparse, len(calls)) == (3, 11)
    refused(cli(*RUN_2D, "--rerun-every", "2"), "--rerun-every")


@row("run --quiet")
def _quiet(cli, key):
    base = [a for a in RUN_2D if a != "--quiet"]
    assert "it/s" in cli(*base, tty=True).err or "step/s" in cli(*base, tty=True).err
    assert cli(*base, "--quiet", tty=True).err == ""


@row("run --nees")
def _run_nees(cli, key):
    plain, scored = cli(*RUN_2D), cli(*RUN_2D, "--nees")
    assert "nees.csv" not in plain.files and "nees_mean" not in plain.metrics()
    lines = scored.text("nees.csv").splitlines()
    assert lines[0] == "step,pose_id,nees" and len(lines) == 1 + 10
    assert scored.metrics()["nees_mean"] > 0
    refused(cli(*RUN_IMAGES, "--nees"), "2-D runs only")
    refused(cli(*RUN_2D, "--dataset", "victoria-park", "--nees"), "needs ground truth")


@row("run --frontend")
def _run_frontend(cli, key):
    differ(cli(*RUN_IMAGES), cli(*RUN_IMAGES, "--frontend", "orb"))
    refused(cli(*RUN_2D, "--frontend", "orb"), "image sequences only")


@row("run --odometry")
def _run_odometry(cli, key):
    differ(cli(*RUN_IMAGES), cli(*RUN_IMAGES, "--odometry", "none"))
    refused(cli(*RUN_2D, "--odometry", "none"), "image sequences only")


@row("run --odometry-noise")
def _run_odometry_noise(cli, key):
    derived = [*RUN_IMAGES, "--odometry", "derived"]
    differ(cli(*derived), cli(*derived, "--odometry-noise", "0.1", "0.5"))
    refused(cli(*RUN_IMAGES, "--odometry-noise", "0.1", "0.5"), "--odometry-noise")


@row("run --loops")
def _run_loops(cli, key):
    res = cli(*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:], "--loops")
    assert res.rc == 0, res.err
    assert {"loops.csv", "loops.jsonl"} <= set(res.files) and "loops" in res.metrics()
    refused(cli(*RUN_2D, "--loops"), "image sequences only")


@row("run --vocab")
def _run_vocab(cli, key, vocab_file=None):
    res = cli(*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:], "--vocab", str(vocab_file))
    assert res.rc == 0, res.err
    assert res.metrics()["loops"]["vocabulary"] == str(vocab_file)
    refused(cli(*RUN_2D, "--vocab", str(vocab_file)), "image sequences only")


@row("run --frames")
def _run_frames(cli, key):
    every = cli(*RUN_IMAGES)
    second = cli(*RUN_IMAGES, "--frames", "2:12:2")
    differ(every, second)
    # frames 2, 4, 6, 8, 10 (--max-steps 5): ground truth sliced the same way
    gt = [line.split()[1:4] for line in second.text("ground_truth.tum").splitlines()
          if not line.startswith("#")]
    full = [line.split()[1:4] for line in cli(*RUN_IMAGES, "--max-steps", "11")
            .text("ground_truth.tum").splitlines() if not line.startswith("#")]
    assert gt == full[2:12:2]
    refused(cli(*RUN_IMAGES, "--frames", "5:5"), "selects no frame")
    refused(cli(*RUN_IMAGES, "--frames", "a:b"), "--frames")
    refused(cli(*RUN_2D, "--frames", "0:5"), "image sequences only")


@row("run --save-map")
def _run_save_map(cli, key):
    from graphslam.maps.files import load_map

    folder = cli.path("map")
    res = cli(*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:], "--frames", "0:10:2", "--save-map",
              str(folder))
    assert res.rc == 0, res.err
    smap = load_map(folder)
    assert smap.keyframe_ids.tolist() == [0, 2, 4, 6, 8] and smap.n_landmarks > 0
    refused(cli(*RUN_IMAGES, "--save-map", str(cli.path("ekf_map"))), "isam2")
    # 2-D runs save a landmark map (tests/graphslam/maps/test_maps2d.py has the rest)
    assert cli(*RUN_2D, "--save-map", str(cli.path("planar_map"))).rc == 0
    refused(cli(*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:], "--map", str(cli.path("planar_map"))),
            "2-D landmark map")


@row("run --map")
def _run_map(cli, key):
    from graphslam.maps.files import load_map

    isam2 = [*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:]]
    first, joint = cli.path("map1"), cli.path("joint")
    assert cli(*isam2, "--max-steps", "12", "--save-map", str(first)).rc == 0
    # the second session starts at frame 3 and is placed by relocalisation in the first map
    res = cli(*isam2, "--frames", "3:", "--map", str(first), "--save-map", str(joint))
    assert res.rc == 0, res.err

    def first_pose(name):
        return [float(v) for v in res.text(name).splitlines()[1].split()[1:4]]

    err = sum((a - b) ** 2 for a, b in zip(first_pose("trajectory.tum"),
                                            first_pose("ground_truth.tum"))) ** 0.5
    assert err < 0.02  # metres: the relocalised anchor, not an assumed start pose
    smap = load_map(joint)
    assert smap.n_keyframes == 12 + 5 and len(smap.meta["sessions"]) == 2
    refused(cli(*RUN_2D, "--map", str(first)), "3-D map")
    refused(cli(*isam2, "--map", str(cli.path("nowhere"))), "map folder not found")
    # without odometry the run's lengths are its own, not the saved map's
    refused(cli(*isam2, "--odometry", "none", "--map", str(first)), "scale of its own")


@row("run --relocalise")
def _run_relocalise(cli, key):
    isam2 = [*RUN_IMAGES[:4], "isam2", *RUN_IMAGES[5:]]
    plain = cli(*isam2)
    res = cli(*isam2, "--relocalise")
    assert res.rc == 0, res.err
    assert "tracking_loss" in res.metrics() and "tracking_loss" not in plain.metrics()
    assert set(res.metrics()["tracking_loss"]) >= {"loss_rule", "losses", "relocalisations", "loss_lengths"}
    assert "active search found fewer than 3 landmarks, or the camera alone could not place the frame (coasted), in 2 frames in a row" in res.metrics()["tracking_loss"]["loss_rule"]
    refused(cli(*RUN_IMAGES, "--relocalise"), "use isam2")
    refused(cli(*RUN_2D, "--relocalise"), "image sequences only")


@row("compare --dataset")
def _compare_dataset(cli, key):
    a = cli(*COMPARE)
    b = cli(*COMPARE, "--dataset", str(_square_graph(cli)))
    differ(a, b, "compare.json")


@row("compare --robot")
def _compare_robot(cli, key):
    mrclam = [*COMPARE, "--dataset", str(SHARED_DATA / "mrclam6"), "--backends", "ekf"]
    one, three = cli(*mrclam), cli(*mrclam, "--robot", "3")
    differ(one, three, "compare.json")
    assert "mrclam6-robot3" in three.text("compare.json")
    refused(cli(*COMPARE, "--robot", "3"), "--robot applies to MRCLAM folders only")


@row("compare --backends")
def _compare_backends(cli, key):
    runs = json.loads(cli(*COMPARE[:4], "isam2", *COMPARE[6:]).files["compare.json"])["runs"]
    assert [r["backend"] for r in runs] == ["isam2"]


@row("compare --seed")
def _compare_seed(cli, key):
    a = json.loads(cli(*COMPARE).files["compare.json"])["runs"][0]["ate_rmse_m"]
    b = json.loads(cli(*COMPARE, "--seed", "7").files["compare.json"])["runs"][0]["ate_rmse_m"]
    assert a != b
    refused(cli(*COMPARE, "--dataset", str(_square_graph(cli)), "--seed", "7"), "--seed")


@row("compare --out")
def _compare_out(cli, key):
    target = cli.path("cmp")
    assert cli(*COMPARE, "--out", str(target)).rc == 0
    assert (target / "compare.json").is_file()


@row("compare --config")
def _compare_config(cli, key):
    a = json.loads(cli(*COMPARE).files["compare.json"])["runs"][0]["ate_rmse_m"]
    cfg = _config(cli, "[synthetic]\nseed = 5\n")
    b = json.loads(cli(*COMPARE, "--config", str(cfg)).files["compare.json"])["runs"][0]["ate_rmse_m"]
    assert a != b


@row("compare --max-steps")
def _compare_max_steps(cli, key):
    runs = json.loads(cli(*COMPARE[:1], *COMPARE[3:], "--max-steps", "5")
                      .files["compare.json"])["runs"]
    assert {r["steps"] for r in runs} == {5}


@row("compare --rerun")
def _compare_rerun(cli, key):
    assert "compare.rrd" in cli(*COMPARE[:-2]).files
    assert "compare.rrd" not in cli(*COMPARE).files


@row("compare --odometry")
def _compare_odometry(cli, key):
    images = ["compare", "--dataset", "synthetic-images", "--max-steps", "5", "--backends",
              "ekf-idp", "--in-process", "--rerun", "off"]
    a = json.loads(cli(*images).files["compare.json"])
    b = json.loads(cli(*images, "--odometry", "none").files["compare.json"])
    assert (a["odometry"], b["odometry"]) == ("sequence", "none")
    assert b["runs"][0]["alignment"] == "sim3" and b["runs"][0]["nees_alignment"] == "gauge"
    refused(cli(*COMPARE, "--odometry", "none"), "image sequences only")


@row("compare --in-process")
def _compare_in_process(cli, key):
    base = ["compare", "--max-steps", "10", "--backends", "isam2", "--rerun", "off"]
    isolated = json.loads(cli(*base).files["compare.json"])["runs"][0]
    inside = json.loads(cli(*base, "--in-process").files["compare.json"])["runs"][0]
    assert isolated.get("peak_rss_mb") is not None and inside.get("peak_rss_mb") is None


def _loops(cli: Cli, *extra: str, tty: bool = False, words: str | None = "100") -> Result:
    csv = cli.path(f"loops{cli.n}.csv")
    res = cli("loops", str(DESK), "--out", str(csv), *(["--words", words] if words else []),
              *([] if tty else ["--quiet"]), *extra, tty=tty)
    assert res.rc == 0, res.err
    res.files["csv"] = csv.read_bytes()
    return res


@row("loops --out")
def _loops_out(cli, key):
    res = _loops(cli)
    assert res.files["csv"].startswith(b"query,match,score,inliers")


@row("loops --vocab")
def _loops_vocab(cli, key, vocab_file=None):
    assert "training a vocabulary" in _loops(cli).err
    assert "training a vocabulary" not in _loops(cli, "--vocab", str(vocab_file), words=None).err
    # --vocab and --words together are refused; neither loads the shipped vocabulary
    assert cli("loops", str(DESK), "--out", str(cli.path("x.csv")), "--words", "10",
               "--vocab", str(vocab_file)).rc == 2
    assert "training a vocabulary" not in _loops(cli, words=None).err


@row("loops --words")
def _loops_words(cli, key):
    assert "100 words" in _loops(cli).err
    assert "10 words" in _loops(cli, "--words", "10").err


@row("loops --intrinsics")
def _loops_intrinsics(cli, key):
    # 10 desk images give no loop candidate to verify, so the check is that the
    # camera reaches the detector's geometric verification (essential matrix).
    import loopclosure.detector as detector

    seen = []
    real = detector.LoopDetector

    class Spy(real):
        def __init__(self, *a, **kw):
            seen.append(kw.get("K"))
            super().__init__(*a, **kw)

    cli.monkeypatch.setattr(detector, "LoopDetector", Spy)
    intr = cli.path("intr.txt")
    intr.write_text("520 521 320 240\n")
    _loops(cli)
    _loops(cli, "--intrinsics", str(intr))
    assert seen[0] is None and seen[1][1, 1] == 521


@row("loops --config")
def _loops_config(cli, key):
    # the desk folder is sparse: "auto" takes it as keyframes and queries from
    # image 3 on; forced to video, the 40-frame window leaves no query at all
    cfg = _config(cli, '[loops]\nmode = "video"\n')
    _loops(cli, "--log", str(cli.path("a.jsonl")))
    _loops(cli, "--log", str(cli.path("b.jsonl")), "--config", str(cfg))
    assert cli.path("a.jsonl").read_text().count("\n") > 0
    assert cli.path("b.jsonl").read_text() == ""


@row("loops --truth")
def _loops_truth(cli, key):
    # the desk's one true pair, as a CSV of names and as a 10x10 image; both
    # give the same figures, and a wrong truth changes them
    import cv2
    import numpy as np

    grid = np.zeros((10, 10), np.uint8)
    grid[9, 0] = 255
    cv2.imwrite(str(cli.path("truth.png")), grid)
    cli.path("truth.csv").write_text("query,match\n10.png,01.png\n")
    cli.path("wrong.csv").write_text("query,match\n09.png,01.png\n")
    outs = [_loops(cli, "--truth", str(cli.path(t)), words=None).out
            for t in ("truth.csv", "truth.png", "wrong.csv")]
    assert "precision 1.000 (1/1), recall 1.000" in outs[0]
    assert "precision 1.000 (1/1), recall 1.000" in outs[1]
    assert "precision 0.000 (0/1), recall 0.000" in outs[2]
    assert "pr.csv" in outs[0] and "pr.png" in outs[0]
    plain = _loops(cli, words=None).out  # writes none, and removes the earlier run's
    assert "pr.csv" not in plain.split("; wrote ")[-1] and "removed from" in plain
    assert not cli.path("pr.csv").exists()


@row("loops --log")
def _loops_log(cli, key):
    log = cli.path("cand.jsonl")
    _loops(cli, "--log", str(log))
    assert log.is_file()


@row("loops --frames")
def _loops_frames(cli, key):
    log_all, log_some = cli.path("all.jsonl"), cli.path("some.jsonl")
    _loops(cli, "--log", str(log_all))
    res = _loops(cli, "--frames", "0:6", "--log", str(log_some))
    assert "6 images" in res.out


@row("loops --quiet")
def _loops_quiet(cli, key):
    assert "img" in _loops(cli, tty=True).err
    assert "img" not in _loops(cli).err


def _train(cli: Cli, *extra: str, tty: bool = False) -> tuple[Result, bytes]:
    out = cli.path(f"v{cli.n}.voc")
    res = cli("vocab", "train", str(DESK), "--words", "100", "--out", str(out),
              *([] if tty else ["--quiet"]), *extra, tty=tty)
    assert res.rc == 0, res.err
    return res, out.read_bytes()


@row("vocab train --out")
def _vocab_out(cli, key):
    assert len(_train(cli)[1]) > 0


@row("vocab train --words")
def _vocab_words(cli, key):
    assert _train(cli)[1] != _train(cli, "--words", "10")[1]


@row("vocab train --flat")
def _vocab_flat(cli, key):
    assert _train(cli)[1] != _train(cli, "--flat")[1]


@row("vocab train --branching")
def _vocab_branching(cli, key):
    assert _train(cli)[1] != _train(cli, "--branching", "5")[1]


@row("vocab train --per-image")
def _vocab_per_image(cli, key):
    assert _train(cli)[1] != _train(cli, "--per-image", "50")[1]


@row("vocab train --seed")
def _vocab_seed(cli, key):
    assert _train(cli)[1] != _train(cli, "--seed", "3")[1]


@row("vocab train --config")
def _vocab_config(cli, key):
    cfg = _config(cli, "[loops.orb]\nn_features = 100\ncell_size_px = 0\n")
    assert _train(cli)[1] != _train(cli, "--config", str(cfg))[1]


@row("vocab train --quiet")
def _vocab_quiet(cli, key):
    assert "img" in _train(cli, tty=True)[0].err
    assert "img" not in _train(cli)[0].err


# --------------------------------------------------------------------------- tests

def test_every_option_has_a_row():
    options = command_options()
    assert options - set(ROWS) == set(), "options without a row"
    assert set(ROWS) - options == set(), "rows for options that no longer exist"


def test_compare_help_lists_image_datasets(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = capsys.readouterr().out
    assert "synthetic-images" in text and "FOLDER" in text and "ekf-ahp" in text
    assert "--odometry" in text and "--frontend" not in text


@pytest.mark.skipif(not DESK.is_dir() or not KITTI07.is_dir(), reason="shared data missing")
@pytest.mark.parametrize("key", sorted(ROWS))
def test_option(key, tmp_path, capsys, monkeypatch, request):
    fn = ROWS[key]
    kw = {}
    if "vocab_file" in fn.__code__.co_varnames[:fn.__code__.co_argcount]:
        kw["vocab_file"] = request.getfixturevalue("vocab_file")
    fn(Cli(tmp_path, capsys, monkeypatch), key, **kw)
