"""Fuzzing the other inputs (issue 34): trajectory files (TUM, KITTI, EuRoC),
image folders and map folders. Every mutant is read into a valid result or
refused with one of our one-line errors, never a traceback; a few go through
the CLI, which exits 0 or 2 with one ``graphslam: error:`` line.

Mutants come from :mod:`tests.fuzzing` (seeded: a failure prints the seed that
reproduces it). The last section holds the plain tests of the bugs the fuzzing
found.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from slamcore.errors import GraphSlamError, InputError
from tests import trajectories as tr
from tests.conftest import ROOT
from tests.fuzzing import Mutator, fuzz, fuzz_cases
from tests.graphslam.sources.test_fuzz import assert_clean
from tests.graphslam.maps.test_maps import random_map
from tests.graphslam.maps.test_maps2d import small_map

#: Mutants per trajectory format, image-folder layout and map kind.
N_TRAJECTORY, N_IMAGE_FOLDER, N_MAP = 300, 60, 150
#: Mutated files run through the CLI per command.
N_CLI = 20
#: One CLI run's limit, seconds (a run of 6 frames takes about a second).
CLI_TIMEOUT_S = 120


def graphslam(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "graphslam", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=CLI_TIMEOUT_S,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"})


def assert_clean_exit(res: subprocess.CompletedProcess, what: str) -> None:
    """Exit 0, or exit 2 with exactly one ``graphslam: error:`` line; no traceback."""
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("graphslam: error:")]
    assert "Traceback" not in res.stderr, f"{what}:\n{res.stderr}"
    assert (res.returncode, len(errors)) in ((0, 0), (2, 1)), \
        f"{what}: exit {res.returncode}, stderr:\n{res.stderr}"


# ------------------------------------------------------------------------------ trajectories

EXTENSION = {"tum": "txt", "kitti": "txt", "euroc": "csv"}


def trajectory_base(fmt: str, shared_data: Path, folder: Path) -> bytes:
    """A small valid file: 30 poses of KITTI 07's ground truth, or the evo test oval."""
    if fmt == "kitti":
        lines = (shared_data / "kitti07" / "poses.txt").read_bytes().splitlines(keepends=True)
        return b"".join(lines[:30])
    return tr.write(folder / f"base.{EXTENSION[fmt]}", fmt, *tr.trajectory(30, False)).read_bytes()


def check_trajectory(trajectory) -> None:
    """Read poses are finite rigid motions; TUM and EuRoC stamps finite and increasing."""
    T = trajectory.wTc
    assert len(T) and np.all(np.isfinite(T))
    R = T[:, :3, :3]
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-2)
    if trajectory.stamps_s is not None:
        assert np.all(np.isfinite(trajectory.stamps_s)) and np.all(np.diff(trajectory.stamps_s) > 0)


def read_and_score(reference: Path):
    """What ``graphslam eval REF MUTANT`` and ``eval MUTANT REF`` do, scores included."""
    from graphslam.evaluation.trajectory import EvalOptions
    from graphslam.pipelines.trajectory_eval import evaluate_files
    from graphslam.sources.ground_truth import read_trajectory

    def read(path: Path):
        trajectory = read_trajectory(path)
        check_trajectory(trajectory)
        results = (evaluate_files(reference, [path], EvalOptions())
                   + evaluate_files(path, [reference], EvalOptions(align="sim3", delta=5,
                                                                  delta_unit="m")))
        for r in results:
            json.dumps(r.result.summary())
        return trajectory

    return read


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # overflow of a huge value, then refused
@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc"])
def test_fuzz_trajectory_reader(tmp_path, shared_data, fmt):
    base = trajectory_base(fmt, shared_data, tmp_path)
    reference = tmp_path / f"ref.{EXTENSION[fmt]}"
    reference.write_bytes(base)
    read_and_score(reference)(reference)  # a valid corpus
    t0 = time.perf_counter()
    findings = fuzz(base, tmp_path / f"mutant.{EXTENSION[fmt]}", read_and_score(reference),
                    N_TRAJECTORY, seed=0)
    assert_clean(findings, t0)


def test_fuzz_eval_cli(tmp_path, shared_data):
    """``graphslam eval`` on mutants of each format: a table or one error line."""
    for k in range(N_CLI):
        fmt = ("tum", "kitti", "euroc")[k % 3]
        base = trajectory_base(fmt, shared_data, tmp_path)
        reference = tmp_path / f"ref.{EXTENSION[fmt]}"
        reference.write_bytes(base)
        mutant = tmp_path / f"mutant.{EXTENSION[fmt]}"
        mutant.write_bytes(Mutator(1000 + k).mutate(base))
        pair = (reference, mutant) if k % 2 else (mutant, reference)
        res = graphslam("eval", *pair, "--out", tmp_path / "out", "--no-plot", cwd=tmp_path)
        assert_clean_exit(res, f"eval {fmt}, seed {1000 + k}")


# ------------------------------------------------------------------------------ image folders

#: KITTI 07 frames of the small KITTI-layout folder (every 5th: parallax enough to run).
KITTI_FRAMES = (0, 5, 10, 15, 20, 25)
#: Desk photos of the plain folder (10 is taken where 01 was).
DESK_PHOTOS = ("01", "02", "03", "10")
#: Odd image names: non-ASCII digits, spaces, a zero-width space, upper case, accents.
ODD_NAMES = ("٣.png", "000003 .png", " 000004.png", "frame 1.png", "²5.png", "0000010.png",
             "00000١.png", "x\u200b.png", "été.png", "000007.PNG", "000999.png")


def kitti_folder(shared_data: Path, folder: Path) -> Path:
    """``image_0/`` with :data:`KITTI_FRAMES` and the sequence's calib, times and poses
    (frames picked by the number in each name)."""
    src = shared_data / "kitti07"
    (folder / "image_0").mkdir(parents=True)
    for k in KITTI_FRAMES:
        name = f"image_0/{k:06d}.png"
        (folder / name).write_bytes((src / name).read_bytes())
    for name in ("calib.txt", "times.txt", "poses.txt"):
        (folder / name).write_bytes((src / name).read_bytes())
    return folder


def desk_folder(shared_data: Path, folder: Path) -> Path:
    """A plain image folder: :data:`DESK_PHOTOS` and an ``intrinsics.txt``."""
    folder.mkdir(parents=True)
    for name in DESK_PHOTOS:
        src = shared_data / "slambook2_desk" / "images" / f"{name}.png"
        (folder / f"{name}.png").write_bytes(src.read_bytes())
    (folder / "intrinsics.txt").write_text("520.9 521.0 325.1 249.7\n")
    return folder


def damage_image_folder(m: Mutator, folder: Path) -> str:
    """One damage to the image folder ``folder`` (in place); says which."""
    images = sorted(p for p in folder.rglob("*") if p.suffix.lower() == ".png" and p.is_file())
    texts = sorted(p for p in folder.glob("*.txt"))
    if not images:
        return "no images left"
    img = m.rng.choice(images)
    op = m.rng.choice(("bytes", "bytes", "empty", "text", "size", "colour", "jpeg", "file",
                       "file", "file", "rename", "remove", "dir", "extra"))
    if op == "bytes":
        img.write_bytes(m.mutate(img.read_bytes()))
    elif op == "empty":
        img.write_bytes(b"")
    elif op == "text":
        img.write_text("not an image\n")
    elif op in ("size", "colour", "jpeg"):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        if gray is None:  # damaged before
            return f"{op} {img.name} (unreadable already)"
        if op == "size":
            h, w = gray.shape
            gray = cv2.resize(gray, m.rng.choice(((w // 2, h), (w, h + 1), (1, 1), (w * 2, 2))))
        elif op == "colour":
            gray = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR).astype(np.uint16) * 257
        ext = ".jpg" if op == "jpeg" else ".png"
        img.write_bytes(cv2.imencode(ext, gray)[1].tobytes())
    elif op == "file":
        if not texts:
            return "no text file left"
        f = m.rng.choice(texts)
        f.write_bytes(m.mutate(f.read_bytes()))
    elif op == "rename":
        img.rename(img.with_name(m.rng.choice(ODD_NAMES)))
    elif op == "remove":
        m.rng.choice(images + texts).unlink()  # the intrinsics, times or truth too
    elif op == "dir":
        (img.parent / "000030.png").mkdir(exist_ok=True)
    else:
        copy = img.with_name(m.rng.choice(ODD_NAMES))
        if copy != img:
            shutil.copy(img, copy)
    return f"{op} {img.name}"


def read_every_frame(folder: Path):
    """What ``run --dataset FOLDER`` reads: the layout, calibration, times and truth,
    then every frame, undistorted, at the sequence's size."""
    from graphslam.sources.spatial.images import read_image_sequence

    seq = read_image_sequence(folder)
    assert len(seq) and np.all(np.isfinite(seq.K))
    if seq.stamps_s is not None:
        assert np.all(np.isfinite(seq.stamps_s)) and np.all(np.diff(seq.stamps_s) > 0)
    if seq.wTc_true is not None:
        assert np.all(np.isfinite(seq.wTc_true)) and len(seq.wTc_true) == len(seq)
    for i in range(len(seq)):
        img = seq.load(i)
        assert img.dtype == np.uint8 and (img.shape[1], img.shape[0]) == tuple(seq.image_size)
    return seq


def image_mutants(base: Path, work: Path):
    """``prepare`` of :func:`fuzz_cases`: ``base`` copied to ``work`` and damaged once or twice."""
    def prepare(m: Mutator) -> tuple[Path, str]:
        shutil.rmtree(work, ignore_errors=True)
        shutil.copytree(base, work)
        done = [damage_image_folder(m, work) for _ in range(m.rng.randint(1, 2))]
        return work, "; ".join(done)

    return prepare


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("layout", ["kitti", "folder"])
def test_fuzz_image_folder(tmp_path, shared_data, layout):
    make = kitti_folder if layout == "kitti" else desk_folder
    base = make(shared_data, tmp_path / "base")
    read_every_frame(base)  # a valid corpus
    t0 = time.perf_counter()
    findings = fuzz_cases(image_mutants(base, tmp_path / "mutant"), read_every_frame,
                          N_IMAGE_FOLDER, seed=0, timeout_s=10.0)
    assert_clean(findings, t0)


#: Seeds of the mutated folders run through the CLI (each damage kind at least once).
CLI_IMAGE_SEEDS = (2000, 2001, 2002, 2003, 2004, 2005)


def test_fuzz_image_folder_cli(tmp_path, shared_data):
    """``graphslam run --dataset FOLDER`` on damaged KITTI folders and ``graphslam loops``
    on damaged plain folders: a run, or one error line and exit 2."""
    kitti = kitti_folder(shared_data, tmp_path / "kitti")
    desk = desk_folder(shared_data, tmp_path / "desk")
    cases = []
    for k, seed in enumerate(CLI_IMAGE_SEEDS):
        base = kitti if k % 2 == 0 else desk
        folder, what = image_mutants(base, tmp_path / f"m{k}")(Mutator(seed))
        cases.append((k, folder, what))
    # a name holding a newline, which a one-line message must not split
    odd = tmp_path / "odd"
    shutil.copytree(desk, odd)
    (odd / "02.png").rename(odd / "0\n2.png")
    (odd / "03.png").write_bytes(b"")
    cases.append((1, odd, "newline name, empty image"))
    for k, folder, what in cases:
        if k % 2 == 0:
            res = graphslam("run", "--dataset", folder, "--rerun", "off", "--quiet",
                            "--out", tmp_path / f"out{k}", cwd=tmp_path)
        else:
            res = graphslam("loops", folder, "--out", tmp_path / f"loops{k}.csv", "--quiet",
                            cwd=tmp_path)
        assert_clean_exit(res, what)


# ------------------------------------------------------------------------------ map folders

def spatial_base(folder: Path) -> Path:
    """A small 3-D map whose meta carries the detectors a localizer builds from it."""
    from frontend.orb import OrbConfig
    from graphslam.maps.files import save_map

    smap = random_map()
    smap.meta.update(tracker={"detector": "orb"}, bow_orb=dataclasses.asdict(OrbConfig()))
    save_map(smap, folder)
    return folder


def planar_base(folder: Path) -> Path:
    """A small 2-D map built, as its meta says, on the default synthetic world."""
    from graphslam.maps.files import save_planar_map
    from graphslam.pipelines.planar_maps import dataset_world

    pmap = small_map()
    pmap.meta["world"] = dataset_world("synthetic", None, None)
    save_planar_map(pmap, folder)
    return folder


def use_spatial_map(folder: Path):
    """``localize``: load the map, build its localizer."""
    from graphslam.maps.files import load_map
    from graphslam.pipelines.localize import make_localizer

    smap = load_map(folder)
    return make_localizer(smap, smap.K)


def use_planar_map(folder: Path):
    """``run --map`` on the synthetic world: load the map, check its world, localiser."""
    from graphslam.pipelines.planar_maps import load_run_map, localiser

    from graphslam import registry

    pmap = load_run_map(folder, registry.load_dataset("synthetic"), None)
    return localiser("ekf", pmap, None, None)


def npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def damage_map(m: Mutator, folder: Path) -> str:
    """One damage to a map folder (in place), its checksum in map.json updated so
    that the damaged file reaches its parser; says which."""
    doc = json.loads((folder / "map.json").read_text())
    entries = [key for key in ("arrays", "vocabulary") if key in doc]
    op = m.rng.choice(("json bytes", "json", "json", "arrays", "arrays", "npz bytes"))
    if op == "json bytes":
        (folder / "map.json").write_bytes(m.mutate((folder / "map.json").read_bytes()))
        return op
    if op == "json":
        doc = m.mutate_json(doc)
        (folder / "map.json").write_text(json.dumps(doc))
        return f"{op}: {json.dumps(doc)[:600]}"
    key = m.rng.choice(entries)
    path = folder / doc[key]["file"]
    if op == "arrays":
        with np.load(path, allow_pickle=False) as z:
            data = npz_bytes(m.mutate_arrays({name: z[name] for name in z.files}))
    else:
        data = m.mutate(path.read_bytes())
    path.write_bytes(data)
    doc[key]["sha256"] = hashlib.sha256(data).hexdigest()
    (folder / "map.json").write_text(json.dumps(doc))
    return f"{op} of {path.name}"


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("kind", ["spatial", "planar"])
def test_fuzz_map_folder(tmp_path, kind):
    base = (spatial_base if kind == "spatial" else planar_base)(tmp_path / "base")
    use = use_spatial_map if kind == "spatial" else use_planar_map
    use(base)  # a valid corpus
    work = tmp_path / "mutant"

    def prepare(m: Mutator) -> tuple[Path, str]:
        shutil.rmtree(work, ignore_errors=True)
        shutil.copytree(base, work)
        return work, damage_map(m, work)

    t0 = time.perf_counter()
    findings = fuzz_cases(prepare, use, N_MAP, seed=0, timeout_s=10.0)
    assert_clean(findings, t0)


# ------------------------------------------------------------------------------ bugs found

def test_trajectory_position_beyond_range_is_refused_at_its_line(tmp_path):
    """A 1e308 coordinate hung ``graphslam eval`` in LAPACK's SVD (an inf in the
    alignment's covariance); it is refused at its line."""
    from graphslam.pipelines.trajectory_eval import load

    lines = tr.write(tmp_path / "t.txt", "tum", *tr.trajectory(10, False)).read_text().splitlines()
    parts = lines[3].split()
    parts[1] = "1e308"
    lines[3] = " ".join(parts)
    (tmp_path / "t.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"t\.txt:4: position beyond 1e\+09 m"):
        load(tmp_path / "t.txt", None, None)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the overflow it refuses
def test_umeyama_refuses_overflowing_points():
    from graphslam.evaluation.spatial import align_umeyama

    src = np.zeros((4, 3))
    src[1, 0] = 1e308
    src[2, 1] = -1e308
    with pytest.raises(GraphSlamError, match="non-finite or overflowing"):
        align_umeyama(src, src.copy())


@pytest.mark.parametrize("kind", [{"a": 1}, ["planar"]])
def test_map_json_kind_not_a_string_is_refused(tmp_path, kind):
    from graphslam.maps.files import load_planar_map

    folder = planar_base(tmp_path / "map")
    doc = json.loads((folder / "map.json").read_text())
    doc["kind"] = kind
    (folder / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"map\.json: damaged map\.json \(kind"):
        load_planar_map(folder)


def test_map_json_nested_too_deeply_is_refused(tmp_path):
    from graphslam.maps.files import load_planar_map

    folder = planar_base(tmp_path / "map")
    (folder / "map.json").write_text("[" * 100_000)
    with pytest.raises(InputError, match="nested too deeply"):
        load_planar_map(folder)


def test_planar_map_world_not_a_table_is_another_world(tmp_path):
    folder = planar_base(tmp_path / "map")
    doc = json.loads((folder / "map.json").read_text())
    doc["meta"]["world"] = -1
    (folder / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="another synthetic world"):
        use_planar_map(folder)


@pytest.mark.parametrize("meta, message", [
    ({"tracker": 5}, "meta 'tracker' is not a table"),
    ({"bow_orb": [1]}, "meta 'bow_orb' is not a table"),
    ({"bow_orb": {"bogus": 1}}, r"meta: unknown key\(s\) \['bogus'\]"),
    ({"tracker": {"detector": "sift"}}, "meta: tracker.detector must be one of"),
])
def test_map_meta_detectors_are_checked_on_load(tmp_path, meta, message):
    """A map's localizer is built from its meta: a detector it cannot build is
    refused when the map is read, naming map.json (was AttributeError, TypeError)."""
    from graphslam.maps.files import load_map

    folder = spatial_base(tmp_path / "map")
    doc = json.loads((folder / "map.json").read_text())
    doc["meta"].update(meta)
    (folder / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"map\.json: damaged map\.json \(" + message):
        load_map(folder)


def rewrite_npz(folder: Path, key: str, change) -> None:
    """``change(arrays)`` applied to the map's ``key`` file (arrays or vocabulary), its
    checksum in map.json updated."""
    doc = json.loads((folder / "map.json").read_text())
    path = folder / doc[key]["file"]
    with np.load(path, allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    change(arrays)
    data = npz_bytes(arrays)
    path.write_bytes(data)
    doc[key]["sha256"] = hashlib.sha256(data).hexdigest()
    (folder / "map.json").write_text(json.dumps(doc))


@pytest.mark.parametrize("field", ["n_words", "format_version"])
def test_vocabulary_field_inf_is_refused(tmp_path, field):
    """int(inf) raised OverflowError out of the vocabulary reader."""
    from graphslam.maps.files import load_map

    folder = spatial_base(tmp_path / "map")
    rewrite_npz(folder, "vocabulary", lambda a: a.update({field: np.array(np.inf)}))
    with pytest.raises(InputError, match=r"vocabulary\.npz: (bad vocabulary field|bad format_version)"):
        load_map(folder)


@pytest.mark.parametrize("kind", ["spatial", "planar"])
def test_map_array_of_one_value_is_refused(tmp_path, kind):
    """A 0-d array (no rows) raised TypeError (len() of unsized object) from the map checks."""
    from graphslam.maps.files import load_map, load_planar_map

    folder = (spatial_base if kind == "spatial" else planar_base)(tmp_path / "map")
    name = "keyframe_ids" if kind == "spatial" else "landmark_ids"
    rewrite_npz(folder, "arrays", lambda a: a.update({name: np.array(5)}))
    with pytest.raises(InputError, match=rf"map\.npz: map array {name} is a single value"):
        (load_map if kind == "spatial" else load_planar_map)(folder)


#: Keyframe 0 holds two words, 1 none, then one each: (words, weights) of the rows.
TWO_WORD_ROWS = np.array([0, 2, 2, 3, 3, 4, 4])


@pytest.mark.parametrize("words, weights, valid", [
    ([0, 3, 0, 0], [0.5, 0.5, 1, 1], True),
    ([3, 3, 0, 0], [0.5, 0.5, 1, 1], False),  # a word twice in a row
    ([3, 0, 0, 0], [0.5, 0.5, 1, 1], False),  # words out of order
    ([0, 3, 0, 0], [0.5, 0.6, 1, 1], False),  # a row summing to 1.1
    ([0, 3, 0, 0], [1.0, 0.0, 1, 1], False),  # a weight of 0
    ([0, 3, 0, 0], [1.5, -0.5, 1, 1], False),  # a negative weight
])
def test_map_bag_of_words_rows_are_checked_on_load(tmp_path, words, weights, valid):
    """A row that is no BowVector loaded, then raised ValueError building the localizer."""
    from graphslam.maps.files import load_map

    folder = spatial_base(tmp_path / "map")
    rewrite_npz(folder, "arrays", lambda a: a.update(
        bow_indptr=TWO_WORD_ROWS, bow_words=np.array(words), bow_weights=np.array(weights)))
    if valid:
        use_spatial_map(folder)
        return
    with pytest.raises(InputError, match=r"map\.npz: map bag-of-words rows are not normalised"):
        load_map(folder)


def test_kitti_frame_numbers_order_the_images(tmp_path, shared_data):
    """0000010.png sorted before 000005.png as text, so frame 10 ran between 0 and 5
    with its stamp out of order; two names of one frame are refused."""
    from graphslam.sources.spatial.images import read_image_sequence

    folder = kitti_folder(shared_data, tmp_path / "kitti")
    (folder / "image_0" / "000010.png").rename(folder / "image_0" / "0000010.png")
    seq = read_image_sequence(folder)
    assert [Path(p).name for p in seq.image_paths][:3] == ["000000.png", "000005.png",
                                                           "0000010.png"]
    assert np.all(np.diff(seq.stamps_s) > 0)
    shutil.copy(folder / "image_0" / "000015.png", folder / "image_0" / "0000015.png")
    with pytest.raises(InputError, match="000015.png and 0000015.png name the same frame"):
        read_image_sequence(folder)
