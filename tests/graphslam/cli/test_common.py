"""The output folder's lock (:func:`graphslam.cli.out_folder.claim_out_dir`): what a command
finds at its ``--out`` when it writes, and what a killed one left there."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from graphslam.cli.out_folder import OutputFolder, claim_out_dir, claimed_folder, release_out_dirs
from slamcore.errors import GraphSlamError


@pytest.fixture
def claimed(tmp_path):
    out = tmp_path / "out"
    claim_out_dir(out)
    yield out
    release_out_dirs()


def test_an_unmoved_folder_is_written_where_it_was(claimed, capsys):
    assert claimed_folder(claimed) == claimed
    assert capsys.readouterr().err == ""


def test_a_renamed_folder_is_written_where_it_now_is(claimed, capsys):
    moved = claimed.with_name("moved")
    claimed.rename(moved)
    assert claimed_folder(claimed).resolve() == moved.resolve()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"was moved to {moved}" in err


def test_a_folder_replaced_at_its_path_is_left_to_its_owner(claimed, capsys):
    # another run made a folder of that name (and may hold its lock): never written into
    moved = claimed.with_name("moved")
    claimed.rename(moved)
    claimed.mkdir()
    assert claimed_folder(claimed).resolve() == moved.resolve()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "names another folder" in err and "left untouched" in err


def test_a_relinked_path_is_not_followed(tmp_path, capsys):
    first, second, link = tmp_path / "first", tmp_path / "second", tmp_path / "out"
    first.mkdir()
    second.mkdir()
    link.symlink_to(first)
    try:
        claim_out_dir(link)
        link.unlink()
        link.symlink_to(second)
        assert claimed_folder(link).resolve() == first.resolve()
    finally:
        release_out_dirs()
    assert "names another folder" in capsys.readouterr().err


def test_a_deleted_folder_is_one_error(claimed):
    shutil.rmtree(claimed)
    with pytest.raises(GraphSlamError, match="was deleted while it ran; its outputs are not written"):
        claimed_folder(claimed)


def test_a_killed_commands_partial_files_are_removed_and_said(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".gs-k1ll3d.part.rrd").write_bytes(b"x" * 100)
    (out / ".gs-other.part").write_bytes(b"")
    (out / "notes.part.txt").write_text("the user's")
    try:
        claim_out_dir(out)
    finally:
        release_out_dirs()
    assert sorted(p.name for p in out.iterdir()) == ["notes.part.txt"]
    said = capsys.readouterr().out
    assert said.count("\n") == 1 and ".gs-k1ll3d.part.rrd" in said and "killed" in said


class _Recorder:
    """A recording whose close succeeds or fails as told (a viewer that went away)."""

    def __init__(self, closes: bool):
        self.closes, self.where = closes, None

    def close(self):
        if not self.closes:
            raise GraphSlamError("the viewer stopped taking the stream")

    def relocate(self, where):
        self.where = where


@pytest.mark.parametrize(
    ("mode", "closes", "listed"), [("save", True, True), ("save", False, False), ("spawn", True, False)]
)
def test_output_folder_lists_a_recording_only_when_it_was_saved_whole(tmp_path, capsys, mode, closes, listed):
    out = tmp_path / "out"
    out.mkdir()
    # an earlier run's (its record of itself), which this one rewrites
    (out / "metrics.json").write_text('{"provenance": {"command": "graphslam run", "code_sha256": "0"}}')
    (out / "run.rrd").write_bytes(b"old")  # an earlier run's recording
    folder = OutputFolder(out, {"metrics.json"} | ({"run.rrd"} if mode == "save" else set()))
    try:
        recorder = folder.open_recorder(lambda m, path, url: _Recorder(closes), mode, "run.rrd", None)
        assert folder.rerun_mode == mode and folder.resolve() == out
        paths = {"metrics": out / "metrics.json"}
        folder.close_recorder(paths)
        folder.finish(paths)
    finally:
        release_out_dirs()
    assert ("recording" in paths) == listed and recorder.where is None
    # an earlier run's recording that this run did not replace whole is not left to read as its own
    assert (out / "run.rrd").exists() == listed
    assert ("the viewer stopped" in capsys.readouterr().err) == (not closes)


def test_output_folder_tells_the_recorder_where_a_moved_folder_went(tmp_path, capsys):
    out = tmp_path / "out"
    folder = OutputFolder(out, set())
    try:
        recorder = folder.open_recorder(lambda m, path, url: _Recorder(True), "save", "run.rrd", None)
        out.rename(tmp_path / "moved")
        assert folder.resolve().resolve() == (tmp_path / "moved").resolve()
        assert recorder.where is not None and Path(recorder.where).resolve() == (tmp_path / "moved").resolve()
    finally:
        release_out_dirs()
    assert "was moved to" in capsys.readouterr().err


@pytest.mark.parametrize("dataset", ["synthetic", "synthetic-images"])
def test_a_map_folder_moved_during_the_run_gets_the_map(tmp_path, monkeypatch, capsys, dataset):
    """--save-map's folder renamed while the run went on: the map went into a new folder
    at the old path, the locked one left empty, and 'map in m/' named the wrong one."""
    from graphslam.cli.main import main
    from graphslam.pipelines import planar, session

    maps, moved = tmp_path / "m", tmp_path / "moved"
    if dataset == "synthetic":
        real = planar.run

        def run_then_move(*args, **kwargs):
            result = real(*args, **kwargs)
            maps.rename(moved)
            return result

        monkeypatch.setattr(planar, "run", run_then_move)
    else:
        real = session.VisualSession.run

        def run_then_move(self, *args, **kwargs):
            result = real(self, *args, **kwargs)
            maps.rename(moved)
            return result

        monkeypatch.setattr(session.VisualSession, "run", run_then_move)
    argv = ["run", "--dataset", dataset, "--max-steps", "30", "--rerun", "off", "--quiet",
            "--out", str(tmp_path / "run"), "--save-map", str(maps)]
    assert main(argv) == 0
    said = capsys.readouterr()
    assert f"--save-map {maps} was moved to {moved}" in said.err
    assert f"map in {moved}/" in said.out
    assert (moved / "map.json").is_file() and not maps.exists()
