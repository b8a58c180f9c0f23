"""A Rerun recording stream (saved, spawned or connected) and the drawing helpers
the 2-D and visual recorders share. With :mod:`.planar` and :mod:`.spatial`, the
only modules that import rerun.
"""

from __future__ import annotations

import errno
import os
import shutil
import socket
import sys
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn
from urllib.parse import urlsplit

import numpy as np

from graphslam.visualisation.layout import LoggedEntities, blueprint, layout_key
from slamcore.errors import ConfigError, GraphSlamError, quote
from slamcore.files import DISK_FULL_REASONS, move_into_place, temporary_beside

#: Where ``connect`` sends the stream without ``--rerun-url`` (the viewer's own default).
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"
#: URL schemes the Rerun SDK accepts, with the port a URL without one means.
VIEWER_URL_SCHEMES = {"rerun+http": 80, "rerun+https": 443, "rerun": 443}
#: gRPC port of a viewer we spawn.
SPAWN_PORT = 9876
#: How long a viewer's port is given to answer: before the run (connect), after
#: starting one (spawn), seconds.
CONNECT_TIMEOUT_S = 1.0
SPAWN_WAIT_S = 5.0
#: Longest wait for a viewer to take the last of the stream at the end, seconds:
#: a viewer that went away must not keep the command from exiting.
FLUSH_TIMEOUT_S = 10.0

#: chi-square 95 % quantile with 2 degrees of freedom.
CHI2_2DOF_95 = 5.991464547107979
_ELLIPSE_POINTS = 33
_CIRCLE = np.stack(
    [np.cos(np.linspace(0, 2 * np.pi, _ELLIPSE_POINTS)), np.sin(np.linspace(0, 2 * np.pi, _ELLIPSE_POINTS))]
)  # (2, P)

GT_COLOR = (160, 160, 160)
PALETTE = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def ellipse_points(centers: np.ndarray, covariances: np.ndarray, chi2: float = CHI2_2DOF_95) -> np.ndarray:
    """(M, P, 2) outline points of the ``chi2`` ellipses of (M, 2) centres, (M, 2, 2) covs."""
    vals, vecs = np.linalg.eigh(covariances)
    axes = vecs * np.sqrt(np.clip(vals, 0.0, None) * chi2)[:, None, :]  # (M, 2, 2)
    return centers[:, None, :] + np.einsum("mij,jp->mpi", axes, _CIRCLE)


class ViewerUnavailable(GraphSlamError):
    """The Rerun viewer a run was to stream to cannot be started or reached."""


class SavedInstead(ViewerUnavailable):
    """The viewer stopped taking the stream during the run, and the copy recorded beside
    it was kept at ``path`` (:meth:`RerunLog._connect`)."""

    def __init__(self, message: str, path: Path):
        super().__init__(message)
        self.path = path


def parse_viewer_url(url: str) -> tuple[str, int]:
    """``(host, port)`` of a viewer gRPC URL such as :data:`DEFAULT_VIEWER_URL`.

    Raises:
        ConfigError: not a ``rerun+http://``, ``rerun+https://`` or ``rerun://``
            URL with a host and the ``/proxy`` path (what the SDK would refuse
            only after the run).
    """
    try:
        parts = urlsplit(url.strip())
        port = parts.port
    except ValueError:  # "Invalid IPv6 URL" (an unclosed '['), a port out of range
        parts, port = urlsplit(""), -1
    if (
        parts.scheme not in VIEWER_URL_SCHEMES
        or not parts.hostname
        or port == -1
        or parts.path.rstrip("/") != "/proxy"
    ):
        raise ConfigError(
            f"Rerun viewer URL {quote(url)} is not like {DEFAULT_VIEWER_URL} "
            f"(schemes: {', '.join(VIEWER_URL_SCHEMES)}; path /proxy)"
        )
    return parts.hostname, port or VIEWER_URL_SCHEMES[parts.scheme]


def find_viewer() -> str | None:
    """Path of the ``rerun`` viewer executable: on PATH, else beside this interpreter
    (a virtualenv's ``bin/``, which is not on PATH when its console script is run
    by its full path)."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    return str(beside) if beside.is_file() and os.access(beside, os.X_OK) else None


def _port_answers(host: str, port: int, timeout_s: float) -> str | None:
    """None when a TCP connection to ``host:port`` succeeds, else why not."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except OSError as e:
        return e.strerror or type(e).__name__


#: What a gRPC client sends first on a plain-text connection (RFC 9113 3.4): the HTTP/2
#: preface and an empty SETTINGS frame. A Rerun viewer (tonic gRPC) answers with a
#: SETTINGS frame of its own.
_HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_HTTP2_SETTINGS = 4


def _speaks_grpc(host: str, port: int, timeout_s: float) -> str | None:
    """None when ``host:port`` answers an HTTP/2 preface with a SETTINGS frame, as a
    Rerun viewer's gRPC server does, else what it did instead. The TCP check alone let
    a run "connect" to any program on the port (a web server: hostile pass 16): nothing
    was recorded, no run.rrd kept, and the end said only "the recording is incomplete".
    Written by hand because the one question, "does it speak HTTP/2", needs no gRPC
    client library."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as s:
            s.sendall(_HTTP2_HELLO)
            head = b""
            while len(head) < 9:
                chunk = s.recv(9 - len(head))
                if not chunk:
                    break
                head += chunk
    except TimeoutError:
        return f"the port answers but says nothing within {timeout_s:g} s"
    except OSError as e:
        return e.strerror or type(e).__name__
    if len(head) == 9 and head[3] == _HTTP2_SETTINGS:
        return None
    if not head:
        return "the port closed the connection without a word"
    shown = head.decode("ascii", "replace").encode("unicode_escape").decode("ascii")
    return f"the port answers, but not as a gRPC server: it began '{shown}'"


def check_recording_path(path: str | Path, flag: str | None = None) -> None:
    """ConfigError unless Rerun can save a recording at ``path``: it takes UTF-8 paths
    only, and a folder named in another encoding (Latin-1 bytes) would fail it after
    the run's work, as a traceback. ``flag`` names the option that gave the path."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        where = f"{flag} {path}" if flag else str(path)
        raise ConfigError(
            f"{where}: not a UTF-8 path, and Rerun saves recordings under UTF-8 paths only; "
            "rename the folder, or pass --rerun off"
        ) from None


def sink_problem(mode: str, url: str | None = None) -> str | None:
    """Why the stream of ``mode`` cannot be used on this machine, or None.

    ``spawn`` needs the viewer executable (:func:`find_viewer`) and, on Linux,
    a display to open its window on; ``connect`` needs a viewer answering at
    ``url`` within :data:`CONNECT_TIMEOUT_S`. ``save`` and ``off`` always work.

    Raises:
        ConfigError: ``url`` is malformed (:func:`parse_viewer_url`).
    """
    if mode == "spawn":
        if find_viewer() is None:
            return "no Rerun viewer executable ('rerun') on PATH or beside the interpreter"
        if sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        ):
            return "no display to open a Rerun viewer on (DISPLAY and WAYLAND_DISPLAY unset)"
    elif mode == "connect":
        url = url or DEFAULT_VIEWER_URL
        host, port = parse_viewer_url(url)
        why = _port_answers(host, port, CONNECT_TIMEOUT_S)
        if why is None and urlsplit(url).scheme == "rerun+http":  # TLS's handshake is not probed
            why = _speaks_grpc(host, port, CONNECT_TIMEOUT_S)
        if why is not None:
            return f"no Rerun viewer answers at {url} ({why})"
    return None


def _wait_for_port(host: str, port: int, wait_s: float) -> bool:
    deadline = time.monotonic() + wait_s
    while True:
        if _port_answers(host, port, 0.2) is None:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.1)


#: How often a save-mode flush looks at its file, and how long after the file met the
#: disk's end a flush still waiting is given up (s): writing what is buffered takes
#: well under a second once the disk is full.
WATCH_S, WEDGED_AFTER_S = 0.5, 5.0
#: Streams whose flush was given up (:meth:`RerunLog._flush_watched`): held so that no
#: drop, disconnect or exit hook waits on them. Process state, not a setting: a Rust
#: thread that never returns.
_WEDGED: list = []


def wedged() -> bool:
    """Whether a recording's flush was given up in this process: the process must then
    end without exit hooks (:func:`os._exit`), which would wait for it forever."""
    return bool(_WEDGED)


def write_limit_reached(path: Path) -> str | None:
    """Why a file just written may have been cut, or None: it reached this process's
    file-size limit, or its file system has no free block left (:func:`disk_full`)."""
    try:
        import resource  # POSIX only

        soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
        if soft != resource.RLIM_INFINITY and path.stat().st_size >= soft:
            return DISK_FULL_REASONS[errno.EFBIG]
    except (ImportError, AttributeError, OSError):
        return None
    return disk_full(path)


def disk_full(path: Path) -> str | None:
    """The full-disk reason when the file system of ``path`` (a file or a folder) has no
    free block left (what root may use, reserved blocks included, or what others may),
    else None. For a folder, not :func:`write_limit_reached`: a folder's own size
    compared with the file-size limit named that limit as the cause under a small ulimit."""
    try:
        st = os.statvfs(path)
    except (AttributeError, OSError):
        return None
    if (st.f_bfree if os.geteuid() == 0 else st.f_bavail) == 0:
        return DISK_FULL_REASONS[errno.ENOSPC]
    return None


class _NotingStream:
    """A RecordingStream that notes what each ``log`` and ``send_columns`` wrote
    (:class:`graphslam.visualisation.layout.LoggedEntities`), for the layout, and
    calls ``on_set_time`` before each ``set_time`` (a step or frame begins)."""

    def __init__(self, stream, logged: LoggedEntities, on_set_time=None):
        self._stream, self._logged, self._on_set_time = stream, logged, on_set_time

    def set_time(self, *args, **kwargs) -> None:
        if self._on_set_time is not None:
            self._on_set_time()
        self._stream.set_time(*args, **kwargs)

    def log(self, path: str, *entities, **kwargs) -> None:
        self._logged.note_log(path, entities)
        self._stream.log(path, *entities, **kwargs)

    def send_columns(self, path: str, indexes, columns, **kwargs) -> None:
        self._logged.note_columns(path, columns)
        self._stream.send_columns(path, indexes, columns, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


class RerunLog:
    """One recording stream, saved to a file, spawned into a viewer, or sent to one.

    ``rec`` is the stream to log to; when the log closes, the viewer layout of
    what was logged (:mod:`graphslam.visualisation.layout`) is sent with it.

    Args:
        mode: "save" (write ``path``), "spawn" (start a local viewer) or
            "connect" (gRPC to ``url``, default the viewer's own default).
        recording_id: fixed id so the same run gives the same recording (with the
            file's name and folder appended when saving: two files, two recordings).
        live_layout: also send the layout during the run, at the first
            ``rec.set_time`` (a new step or frame) after it changed (default:
            for a live viewer, not for a file, which gets it once, at the close).
    """

    def __init__(
        self,
        mode: str,
        path: Path | None = None,
        url: str | None = None,
        application_id: str = "graphslam",
        recording_id: str = "graphslam-run",
        live_layout: bool | None = None,
    ):
        # Rerun's Rust side reads RUST_LOG once, at import: unset, its coloured ERROR/WARN
        # lines (a full disk under the file writer) spilled onto stderr before our one
        # warning, which says the same with its cause. A user's own RUST_LOG is kept.
        os.environ.setdefault("RUST_LOG", "off")
        import rerun as rr  # imported here: no work at import time, and only this module

        self._rr = rr
        # one id a file: recordings of one id opened together are merged into one by the
        # viewer (a run's beside its localisation's); still the same id run to run
        if path is not None:  # (a name that is not UTF-8 is refused below, with its file)
            where = f"{Path(path).name}:{Path(path).parent.name}"
            where = where.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
            recording_id = f"{recording_id}:{where}"
        self._stream = rr.RecordingStream(application_id, recording_id=recording_id)
        self._partial: Path | None = None
        #: a viewer stream's copy on disk (:meth:`_connect`), kept if the viewer goes
        self._backup: Path | None = None
        self._url: str | None = None  # the viewer's, in spawn and connect modes
        self.logged = LoggedEntities()
        self._live_layout = mode != "save" if live_layout is None else live_layout
        # (logged.version, layout_key) at the last check
        self._layout_seen: tuple[int, tuple | None] = (0, None)
        self.rec = _NotingStream(self._stream, self.logged, on_set_time=self._live_check)
        if mode == "save":
            if path is None:
                raise ConfigError("rerun: mode 'save' needs a path")
            check_recording_path(path)
            # Recorded under a temporary name and moved over ``path`` by close():
            # an earlier run's recording stays whole beside its other files until
            # this run ends, and a run that dies leaves no stub (the finalizer).
            self._partial = temporary_beside(Path(path))
            weakref.finalize(self, self._partial.unlink, missing_ok=True)
            try:
                self.rec.save(str(self._partial))
            except RuntimeError as e:  # Rerun's writer could not start (hostile pass 18:
                # a pose-graph run's recording, opened after its files filled the disk)
                self._partial.unlink(missing_ok=True)
                reason = disk_full(self._partial.parent) or str(e).splitlines()[0]
                raise ViewerUnavailable(
                    f"the recording could not be started ({reason}); no {Path(path).name} is kept"
                ) from None
        elif mode == "spawn":
            # Started by path (it may not be on PATH) and without connecting, so a
            # viewer that dies at once (no display) is noticed here, not as a
            # stream that never drains at the end of the run.
            exe = find_viewer()
            if exe is None:
                raise ViewerUnavailable("no Rerun viewer executable ('rerun') found")
            rr.spawn(port=SPAWN_PORT, connect=False, executable_path=exe, recording=self._stream)
            if not _wait_for_port("127.0.0.1", SPAWN_PORT, SPAWN_WAIT_S):
                raise ViewerUnavailable(
                    f"the Rerun viewer started ({exe}) did not open "
                    f"port {SPAWN_PORT} within {SPAWN_WAIT_S:.0f} s"
                )
            self._connect(f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy", path)
        elif mode == "connect":
            parse_viewer_url(url or DEFAULT_VIEWER_URL)
            self._connect(url or DEFAULT_VIEWER_URL, path)
        else:
            raise ConfigError(f"rerun: unknown mode {mode!r} (save, spawn, connect)")
        self.mode = mode
        self.path = path

    def _connect(self, url: str, path: Path | None) -> None:
        """Stream to the viewer at ``url`` and, given ``path``, to a hidden file beside
        it: a viewer closed during the run (its window shut, its machine gone) took the
        recording with it, and the run's only record was a warning. close() deletes the
        copy when the viewer took everything and moves it to ``path`` when it did not."""
        self._url = url
        if path is not None:
            try:
                check_recording_path(path)
                backup = temporary_beside(Path(path))
            except (GraphSlamError, OSError):  # no copy where none can be written
                backup = None
            if backup is not None:
                self._backup = backup
                weakref.finalize(self, backup.unlink, missing_ok=True)
                self._stream.set_sinks(self._rr.GrpcSink(url), self._rr.FileSink(str(backup)))
                return
        self.rec.connect_grpc(url)

    def set_step(self, step: int, stamp_s: float | None = None) -> None:
        """What follows is logged at ``step`` and, with a stamp, at that time; without
        one, on no time at all: Rerun keeps a timeline's last value, so a step without
        a stamp was logged at whatever time an earlier row had set."""
        self.rec.set_time("step", sequence=int(step))
        if stamp_s is not None:
            self.rec.set_time("time", duration=float(stamp_s))
        else:
            self.rec.disable_timeline("time")

    def _live_check(self) -> None:
        """Before each ``set_time``: send the layout if its views changed since the last
        one sent (not for every new entity inside a view: each send resets what the
        user arranged). An integer comparison when nothing new was logged."""
        if not self._live_layout or self.logged.version == self._layout_seen[0]:
            return
        key = layout_key(self.logged)
        changed = key != self._layout_seen[1]
        self._layout_seen = (self.logged.version, key)
        if not changed:
            return
        try:
            self._send_layout()
        except Exception:  # an extra mid-run: never the run's end; close() tries again and says why
            self._live_layout = False

    def _send_layout(self) -> None:
        layout = blueprint(self.logged)
        if layout is not None:
            self._stream.send_blueprint(layout, make_active=True, make_default=True)

    def close(self) -> None:
        """Send the layout, flush and close the stream.

        Raises:
            ViewerUnavailable: a viewer stopped taking the stream; after at most
                :data:`FLUSH_TIMEOUT_S` the rest is dropped.
        """
        try:  # the layout is an extra: whatever it meets, the logged data is flushed
            self._send_layout()
        finally:
            self._flush_and_disconnect()
            if self._partial is not None and self.path is not None:  # save mode: both set
                move_into_place(self._partial, Path(self.path))
                self._partial = None

    def relocate(self, folder: Path) -> None:
        """The output folder was moved during the run (:func:`graphslam.cli.out_folder.claimed_folder`):
        the recording, written through its open file, moved with it; close() moves it
        into place there."""
        if self._partial is not None and self.path is not None:
            self._partial = Path(folder) / self._partial.name
            self.path = Path(folder) / Path(self.path).name
        if self._backup is not None and self.path is not None:
            self._backup = Path(folder) / self._backup.name
            self.path = Path(folder) / Path(self.path).name

    def discard(self) -> None:
        """Stop recording and delete what was recorded: the run ended without its
        outputs, and ``path`` keeps the earlier run's recording, if any."""
        self.rec.disconnect()
        for temporary in (self._partial, self._backup):
            if temporary is not None:
                temporary.unlink(missing_ok=True)
        self._partial = self._backup = None

    def _flush_and_disconnect(self) -> None:
        if self.mode != "save":
            self._close_viewer()
            return
        try:
            if self._partial is not None and self.path is not None:
                self._flush_watched(self._partial, self._not_written)
            else:
                self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as e:
            self.rec.disconnect()
            reason = str(e).splitlines()[0]
            if self._partial is not None and self.path is not None:
                # the writer's death ("File-writer thread shut down prematurely") says no
                # cause; a file at the disk's end or the size limit is that cause
                self._not_written(write_limit_reached(self._partial) or reason)
            raise ViewerUnavailable(
                f"the Rerun viewer stopped taking the stream; the recording is incomplete ({reason})"
            ) from None
        self.rec.disconnect()
        if self._partial is not None and self.path is not None:
            # Rerun's file sink can meet a full disk, log it and still flush "fine",
            # leaving a recording cut at the disk's end
            cut = write_limit_reached(self._partial)
            if cut is not None:
                self._not_written(cut)

    def drop_disk_copy(self) -> bool:
        """A viewer stream (``spawn``, ``connect``): stop writing its copy on disk
        (:meth:`_connect`) and delete it, the viewer still taking the stream; a full
        disk gives the run's own files the room. True when there was a copy."""
        if self._backup is None or self._url is None:
            return False
        backup, self._backup = self._backup, None
        # the file sink is flushed and closed as it is replaced: its space comes free
        self._stream.set_sinks(self._rr.GrpcSink(self._url))
        backup.unlink(missing_ok=True)
        return True

    def _close_viewer(self) -> None:
        """Flush and close a viewer stream (``spawn``, ``connect``) and settle its copy
        on disk (:meth:`_connect`): deleted when the viewer took everything, else moved
        to ``path``.

        Raises:
            SavedInstead: the viewer stopped taking the stream; the copy is now ``path``.
            ViewerUnavailable: the same without a copy (or one cut by a full disk).
        """
        backup, self._backup = self._backup, None

        def copy_cut(reason: str) -> NoReturn:  # a flush wedged on a full disk
            assert backup is not None
            backup.unlink(missing_ok=True)
            raise ViewerUnavailable(
                f"the recording's copy on disk could not be written ({reason}); "
                "the viewer keeps what it received"
            )

        failed: str | None = None
        try:
            if backup is not None:
                self._flush_watched(backup, copy_cut)
            else:
                self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as e:
            failed = str(e).splitlines()[0]
        self.rec.disconnect()
        if failed is None:
            # a viewer killed during the run (SIGKILL, its machine gone) fails no flush:
            # what the stream sent after went nowhere, unsaid; asked again, it is gone
            failed = sink_problem("connect", self._url)
        if failed is None:
            if backup is not None:
                backup.unlink(missing_ok=True)
            return
        if backup is None or self.path is None:
            raise ViewerUnavailable(
                f"the Rerun viewer stopped taking the stream; the recording is incomplete ({failed})"
            )
        cut = write_limit_reached(backup)
        if cut is not None:
            backup.unlink(missing_ok=True)
            raise ViewerUnavailable(
                f"the Rerun viewer stopped taking the stream ({failed}) and the recording's copy "
                f"on disk could not be written ({cut}); the recording is incomplete"
            )
        path = Path(self.path)
        move_into_place(backup, path)
        # never reached or lost midway: the copy on disk is the recording either way (it
        # read "stopped during the run" of a viewer never reached, after a line saying an
        # earlier run.rrd was removed because this command would write none: hostile pass 22)
        raise SavedInstead(
            f"the Rerun viewer did not take the whole stream ({failed}); {path.name} holds the "
            "whole recording instead, written from the copy kept for that case",
            path,
        )

    def _flush_watched(self, partial: Path, give_up: Callable[[str], NoReturn]) -> None:
        """Flush a save-mode stream while watching its file. When Rerun's file writer dies
        on a full disk in the middle of a flush, rerun-sdk 0.41 can wait for it forever
        (1 of 12 runs of ``compare --rerun save`` under a 300 kB file-size limit); a flush still waiting
        :data:`WEDGED_AFTER_S` after the file reached the disk's end (or the process's
        file-size limit) is given up: the recording is not kept, and the stream is held
        in :data:`_WEDGED` so that nothing waits on it again (see :func:`wedged`)."""
        done = threading.Event()
        failed: list[BaseException] = []

        def flush() -> None:
            try:
                self.rec.flush(timeout_sec=1e38)
            except BaseException as e:  # handed to the caller's thread below
                failed.append(e)
            finally:
                done.set()

        threading.Thread(target=flush, name="rerun-flush", daemon=True).start()
        full_since: float | None = None
        while not done.wait(WATCH_S):
            if write_limit_reached(partial) is None:
                full_since = None
            elif full_since is None:
                full_since = time.monotonic()
            elif time.monotonic() - full_since >= WEDGED_AFTER_S:
                _WEDGED.append(self._stream)
                self._rr.unregister_shutdown()  # rerun's exit hook would flush it again
                give_up(f"{write_limit_reached(partial)}; Rerun's writer stopped")
        if failed:
            raise failed[0]

    def _not_written(self, reason: str) -> NoReturn:
        """A recording file that could not be written whole: nothing of it is kept, and
        an earlier run's recording at its name goes too, so the folder never shows that
        recording beside this run's files. Raises ViewerUnavailable saying so."""
        assert self._partial is not None and self.path is not None  # save mode
        self._partial.unlink(missing_ok=True)
        self._partial = None
        Path(self.path).unlink(missing_ok=True)
        raise ViewerUnavailable(
            f"the recording could not be written ({reason}); no {Path(self.path).name} is kept"
        )
