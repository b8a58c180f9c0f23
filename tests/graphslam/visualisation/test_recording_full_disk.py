"""A recording meets a full disk (seventh hostile pass): Rerun's file sink may log the
failure and flush "fine" with the file cut, or its flush may wait forever for a writer
that died. Either way the recording is said not kept, and the process can end."""

from __future__ import annotations

import threading

import pytest

from graphslam.visualisation import recording


def _log(tmp_path):
    log = recording.RerunLog("save", tmp_path / "run.rrd")
    log.rec.log("x", log._rr.Points2D([[0.0, 0.0]]))
    return log


def test_a_flush_that_never_returns_on_a_full_disk_is_given_up(tmp_path, monkeypatch):
    log = _log(tmp_path)
    (tmp_path / "run.rrd").write_bytes(b"an earlier run's recording")
    stuck = threading.Event()
    monkeypatch.setattr(log.rec, "flush", lambda timeout_sec: stuck.wait(), raising=False)
    monkeypatch.setattr(recording, "write_limit_reached", lambda path: "no space left on device")
    monkeypatch.setattr(recording, "WATCH_S", 0.01)
    monkeypatch.setattr(recording, "WEDGED_AFTER_S", 0.05)
    monkeypatch.setattr(recording, "_WEDGED", [])
    monkeypatch.setattr(log._rr, "unregister_shutdown", lambda: None)
    with pytest.raises(recording.ViewerUnavailable, match="Rerun's writer stopped.*no run.rrd is kept"):
        log.close()
    assert recording.wedged()  # the CLI then ends with os._exit, no exit hook waits
    assert not (tmp_path / "run.rrd").exists() and not list(tmp_path.glob("*.part.rrd"))
    stuck.set()


def test_a_flush_that_returns_with_the_file_cut_is_not_kept(tmp_path, monkeypatch):
    log = _log(tmp_path)
    monkeypatch.setattr(recording, "write_limit_reached", lambda path: "no space left on device")
    with pytest.raises(recording.ViewerUnavailable, match=r"\(no space left on device\); no run.rrd"):
        log.close()
    assert not (tmp_path / "run.rrd").exists() and not recording.wedged()


def test_a_recording_on_a_disk_with_room_is_kept(tmp_path):
    log = _log(tmp_path)
    log.close()
    assert (tmp_path / "run.rrd").stat().st_size > 0 and not recording.wedged()


def test_a_recording_path_that_is_not_utf8_is_one_error(tmp_path):
    # Rerun takes UTF-8 paths only: a folder named in Latin-1 raised UnicodeEncodeError
    # from its save(), a traceback (after a pose graph's solve, or a comparison)
    import os

    from slamcore.errors import ConfigError

    folder = tmp_path / os.fsdecode(b"sortie_\xe9")
    folder.mkdir()
    with pytest.raises(ConfigError, match="not a UTF-8 path") as e:
        recording.RerunLog("save", folder / "run.rrd")
    assert "--rerun off" in str(e.value)
    assert not list(folder.iterdir())  # no temporary file left
    recording.check_recording_path(tmp_path / "run.rrd")  # a UTF-8 path passes
