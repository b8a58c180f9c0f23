"""A command's output folder from its claim to its last file: locked so that two
commands never write one folder, cleared of the outputs an earlier command left that
this one will not write, found again where it is just before the files are written
(a folder moved or deleted while the run went on), and the Rerun recording kept in it
opened, told where the folder went, closed and listed only when whole.

:class:`OutputFolder` is that sequence with its state (the path, the flag that named
it, the recording and the mode it ended in): run, compare and localize walk it the same
way. The functions below it are its steps, also used alone by commands that write one
file or none (eval, sweep, loops)."""

from __future__ import annotations

import os
from pathlib import Path

from graphslam.cli.common import warn
from slamcore.errors import GraphSlamError

#: Output folders this command has locked (:func:`claim_out_dir`): path -> descriptor.
_claimed: dict[Path, int] = {}
#: The same descriptors by the path the command was given (absolute, links kept):
#: :func:`claimed_folder` looks there for the folder it locked.
_claimed_as: dict[Path, int] = {}


def clear_earlier_outputs(out_dir: Path, will_write, known: tuple[str, ...] | None = None) -> None:
    """Remove from ``out_dir`` the earlier outputs this command will not write
    (:func:`graphslam.outputs.writers.remove_stale_outputs`, by default every
    command's names) and say which: a file the user may have wanted (a ``loops.csv``
    of the loops command) is never deleted without a word."""
    from graphslam.outputs.writers import FOLDER_OUTPUT_NAMES, remove_stale_outputs

    if known is None:  # run, compare, localize: a sweep's table and runs are not theirs to remove
        from graphslam.pipelines.sweep import sweep_output_names

        refuse_other_outputs(out_dir, sweep_output_names(out_dir), "graphslam sweep")
        _refuse_files_of_unknown_origin(out_dir, will_write, FOLDER_OUTPUT_NAMES)
    removed = remove_stale_outputs(out_dir, will_write, FOLDER_OUTPUT_NAMES if known is None else known)
    if removed:
        # a recording streamed to a viewer is written all the same if the viewer fails
        # (recording.SavedInstead): "no such file" then read as a promise broken
        streamed = any(p.suffix == ".rrd" for p in removed)
        print(
            f"removed from {out_dir}/ an earlier command's {', '.join(p.name for p in removed)} "
            + (
                "(this one writes none of these, a recording only if a viewer it streams to "
                "does not take it: they would read as its own)"
                if streamed
                else "(this one writes no such file: they would read as its own)"
            )
        )


#: The files in which a graphslam command records itself (``provenance``): one of them in a
#: folder shows that its other output names are an earlier command's too.
RECORDS = ("metrics.json", "compare.json", "eval.json")


def holds_a_record(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds a graphslam command's record of itself (:data:`RECORDS`
    with its ``provenance``)."""
    import json

    for name in RECORDS:
        try:
            doc = json.loads((Path(out_dir) / name).read_text())
        except (OSError, ValueError):
            continue
        provenance = doc.get("provenance") if isinstance(doc, dict) else None
        if isinstance(provenance, dict) and "command" in provenance and "code_sha256" in provenance:
            return True
    return False


def _refuse_files_of_unknown_origin(out_dir: Path, will_write, names) -> None:
    """GraphSlamError when ``out_dir`` holds files of our output names that this command
    would remove and no earlier graphslam command is shown to have written there (no
    record of one, :data:`RECORDS`): a user's own ``graph.g2o`` and ``closures.csv`` in
    the folder given as ``--out`` were deleted as "an earlier command's" (nineteenth
    hostile pass)."""
    stale = [n for n in names if n not in will_write and (Path(out_dir) / n).is_file()]
    if not stale or holds_a_record(out_dir):
        return
    raise GraphSlamError(
        f"--out {out_dir} holds {', '.join(stale)}, which this command does not write and no "
        "graphslam command is shown to have written there (no metrics.json, compare.json or "
        "eval.json of one): they would be removed; move them away, or choose another --out"
    )


def refuse_other_outputs(out_dir: Path, names, command: str, flag: str = "--out") -> None:
    """Refuse a folder holding another command's outputs (``names``) that this one neither
    writes nor may remove: a run into a sweep's folder, or a sweep into a run's, left both
    commands' files side by side, read as one set, with nothing said."""
    found = [name for name in names if (Path(out_dir) / name).is_file()]
    if found:
        raise GraphSlamError(
            f"{flag} {out_dir} holds the outputs of {command} ({', '.join(found)}); this command's "
            f"would stand beside them as one set: choose another {flag}, or move them away"
        )


def claim_out_dir(out_dir: Path, flag: str = "--out") -> Path:
    """Create ``out_dir`` and lock it for this command: two commands writing one folder
    at the same time left a mix of both runs' files, each one whole, with nothing said.
    The second is refused in one line instead. The lock is an ``flock`` on the folder
    itself: no lock file is left behind, and the system drops it when the process ends,
    however it ends. A file system without ``flock`` (some network mounts) runs unlocked,
    as before. :func:`release_out_dirs` (main, as the command returns) unlocks."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # the default runs/... in a read-only folder was a traceback
        where = "" if out_dir.is_absolute() else f" in {os.getcwd()}"
        raise GraphSlamError(f"{flag} {out_dir}: cannot create it{where} ({e.strerror or e})") from None
    key = Path(os.path.realpath(out_dir))
    if key in _claimed:
        return out_dir
    try:
        import fcntl
    except ImportError:  # not POSIX: no advisory locks
        return out_dir
    fd = os.open(out_dir, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise GraphSlamError(
            f"{flag} {out_dir}: another graphslam command is writing this folder now; "
            f"wait for it to end, or choose another {flag}"
        ) from None
    except OSError:
        os.close(fd)
        return out_dir
    _claimed[key] = fd
    _claimed_as[Path(os.path.abspath(out_dir))] = fd
    remove_stale_partials(out_dir)
    return out_dir


def remove_stale_partials(out_dir: Path) -> None:
    """Remove the temporary files (``.gs-*.part*``, :func:`slamcore.files.temporary_beside`)
    a killed command left in ``out_dir``, and say so: a SIGKILL'd run's 10 MB hidden
    partial recording stayed forever. Called with the folder's lock held, so no live
    command of ours is writing them."""
    removed = []
    for p in sorted(Path(out_dir).glob(".gs-*.part*")):
        try:
            if p.is_file() and not p.is_symlink():
                p.unlink()
                removed.append(p.name)
        except OSError:  # another user's: left, as any file not ours to remove
            continue
    if removed:
        print(
            f"removed from {out_dir}/ {len(removed)} partial file(s) of a command that was killed: "
            + ", ".join(removed)
        )


def claimed_folder(out_dir: Path, recorder=None, flag: str = "--out") -> Path:
    """Where the folder :func:`claim_out_dir` locked is now, checked just before the
    outputs are written: renamed, deleted or replaced (a symbolic link re-pointed) during
    the run, the path named another folder, possibly one another run has locked, and the
    outputs went there.

    Moved (still there under another name): its new path, after one warning line -- the
    folder is the one this command locked, so writing there keeps the run's work and
    never touches another command's folder (what is now at ``out_dir`` is left alone).
    Deleted: GraphSlamError, nothing can be written into it. Unlocked (no ``flock``):
    ``out_dir``, unchecked. ``recorder``: the run's open recording, told where it is."""
    where = moved_to(out_dir, flag)
    if where is None:
        return out_dir
    if not os.path.exists(out_dir):  # nothing (stat fails) at the path now
        warn(f"{flag} {out_dir} was moved to {where} while this command ran; its outputs go there")
    else:
        warn(
            f"{flag} {out_dir} names another folder since this command began (renamed, or a link "
            f"re-pointed); its outputs go into the folder it locked, now {where}; the other is left untouched"
        )
    if recorder is not None:
        recorder.relocate(where)
    return where


def moved_to(out_dir: Path, flag: str = "--out") -> Path | None:
    """The path the folder :func:`claim_out_dir` locked has now when ``out_dir`` no longer
    names it (renamed, or a link re-pointed), else None (also unlocked: unchecked).
    Deleted, or moved where this system cannot say: GraphSlamError."""
    fd = _claimed_as.get(Path(os.path.abspath(out_dir)))
    if fd is None:
        return None
    held = os.fstat(fd)
    try:
        now = os.stat(out_dir)
    except OSError:
        now = None
    if now is not None and (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
        return None
    try:
        where = os.readlink(f"/proc/self/fd/{fd}")  # Linux: a moved folder's new path
    except OSError:
        where = None
    if held.st_nlink == 0 or where is None or where.endswith(" (deleted)") or not os.path.isdir(where):
        gone = (
            "was deleted" if held.st_nlink == 0 else "was moved or deleted (where to, this system cannot say)"
        )
        raise GraphSlamError(
            f"{flag} {out_dir}: the folder this command locked {gone} while it ran; its outputs are not "
            "written" + ("" if now is None else f" (nor into the other folder now at {out_dir})")
        )
    return Path(where)


def release_out_dirs() -> None:
    """Unlock every folder :func:`claim_out_dir` locked (the command has returned)."""
    _claimed_as.clear()
    while _claimed:
        os.close(_claimed.popitem()[1])


def open_recorder(open_fn, mode: str, path: Path, url: str | None):
    """``(recorder, mode used)``: ``open_fn(mode, path, url)``, falling back to
    saving ``path`` when the viewer fails to start after all."""
    from graphslam.pipelines.common import signal_hook
    from graphslam.visualisation.recording import ViewerUnavailable

    try:
        opened = open_fn(mode, path, url), mode
    except (ViewerUnavailable, GraphSlamError) as e:
        if mode == "save":  # saving is the fallback: it failing is the command's error
            raise
        warn(f"{e}; saving {path.name} instead")
        opened = open_fn("save", path, None), "save"
    signal_hook("recorder")
    return opened


def close_recorder(recorder) -> str:
    """Close a recorder; a viewer that stopped taking the stream, or a recording
    process that failed, is a warning (the run's files are written by then, and the
    steps after this one -- the map, the summary -- must still run). Returns
    ``"whole"`` (closed whole), ``"saved"`` (the viewer went during the run and its
    copy was kept as the recording file) or ``"broken"``."""
    from graphslam.visualisation.recording import SavedInstead, ViewerUnavailable

    try:
        recorder.close()
    except SavedInstead as e:
        warn(str(e))
        return "saved"
    except (ViewerUnavailable, GraphSlamError) as e:
        warn(str(e))
        return "broken"
    return "whole"


class OutputFolder:
    """One command's output folder through the command.

    ``OutputFolder(path, will_write)`` claims ``path`` (:func:`claim_out_dir`) and
    removes the earlier outputs it will not write (``will_write``: file names;
    None keeps them until :meth:`finish`). :meth:`open_recorder` opens the recording
    in it; :meth:`resolve` is where the folder is now, just before the writes;
    :meth:`close_recorder` closes the recording and lists it in the written paths
    when it was kept; :meth:`finish` removes what the command did not write after
    all (a file the disk refused, a recording not kept)."""

    def __init__(self, path: Path, will_write: set[str] | None = None, flag: str = "--out") -> None:
        self.path = claim_out_dir(path, flag)
        self.flag = flag
        self.recorder = None
        #: the recording's stream after a fallback (a viewer that failed is a saved file)
        self.rerun_mode = "off"
        self._recording_name: str | None = None
        if will_write is not None:
            clear_earlier_outputs(self.path, will_write)

    def open_recorder(self, open_fn, mode: str, file_name: str, url: str | None):
        """The recorder ``open_fn(mode, path, url)`` opens on ``file_name`` in this
        folder (:func:`open_recorder`: a viewer that fails to start is a saved file)."""
        self.recorder, self.rerun_mode = open_recorder(open_fn, mode, self.path / file_name, url)
        self._recording_name = file_name
        return self.recorder

    def resolve(self) -> Path:
        """Where the claimed folder is now (:func:`claimed_folder`), the recorder told."""
        self.path = claimed_folder(self.path, self.recorder, self.flag)
        return self.path

    def give_up_recording(self) -> bool:
        """A full disk refused one of the run's own files: a recording still being saved
        in this folder goes, with a warning, to make room for them (hostile pass 17: the
        recording's partial file held the disk and every text file was lost). True when
        one went. A viewer's stream keeps going, its copy on disk goes."""
        if self.recorder is None:
            return False
        if self.rerun_mode != "save":
            return self._give_up_disk_copy()
        recorder, self.recorder = self.recorder, None
        try:
            recorder.discard()
        except Exception:  # noqa: BLE001 - the write's own error is the one to report
            return False
        warn(
            f"the disk is full: the recording ({self._recording_name}) is given up so that the run's "
            "own files fit"
        )
        return True

    def _give_up_disk_copy(self) -> bool:
        drop = getattr(self.recorder, "drop_disk_copy", None)
        try:
            dropped = bool(drop()) if drop is not None else False
        except Exception:  # noqa: BLE001 - the write's own error is the one to report
            return False
        if dropped:
            warn(
                "the disk is full: the recording's copy on disk is given up so that the run's own "
                "files fit (the viewer keeps the stream; a viewer closed from now on loses it)"
            )
        return dropped

    def close_recorder(self, paths: dict[str, Path]) -> None:
        """Close the recording; a saved one closed whole is listed in ``paths`` as
        ``recording`` (a recording not kept is not listed)."""
        if self.recorder is None:
            return
        closed = close_recorder(self.recorder)
        if self._recording_name and (closed == "saved" or closed == "whole" and self.rerun_mode == "save"):
            paths["recording"] = self.path / self._recording_name

    def finish(self, paths: dict[str, Path]) -> None:
        """Remove the earlier outputs that none of ``paths`` replaced."""
        clear_earlier_outputs(self.path, {p.name for p in paths.values()})
