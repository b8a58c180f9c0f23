"""Files written whole or not at all, and output paths checked before a run.

A writer that is cut (a signal, a full disk, a crash) must leave either the old
complete file or the new complete one, never half of the new one: every output
is written to a temporary file in the same folder and moved over the target
with :func:`os.replace`, which is atomic on POSIX and Windows.
"""

from __future__ import annotations

import errno
import functools
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from slamcore.errors import ConfigError

#: Write failures that are the disk's, not ours, by errno: what the one line says.
DISK_FULL_REASONS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file larger than this system allows (a file-size limit)",
}
#: Longest file or folder name most file systems take (ext4, XFS, Btrfs, tmpfs, APFS), bytes.
NAME_MAX_BYTES = 255
#: Longest path Linux takes (PATH_MAX, 4096 with its terminating zero), bytes.
PATH_MAX_BYTES = 4095
#: Longest suffix a temporary file keeps (".npz", ".png"); a longer one is not a format.
MAX_SUFFIX_BYTES = 16


def write_error_line(e: OSError) -> str | None:
    """The one line for an OSError met writing that the user can act on (a full disk,
    a file-size limit, a name too long, a folder in an output's place, a file the user
    may not replace), or None for any other (a bug: the traceback is wanted)."""
    where = short_path(e.filename) if e.filename is not None else "an output file"
    if e.errno in DISK_FULL_REASONS:
        return f"{DISK_FULL_REASONS[e.errno]} writing {where}: {e.strerror}"
    if e.errno == errno.ENAMETOOLONG:
        return f"{where}: a file or folder name is too long ({e.strerror})"
    if e.errno in (errno.EPERM, errno.EACCES):
        # an output the user may not replace (another user's file in a shared folder, an
        # immutable one): the rename names the temporary file first and the output second
        target = short_path(e.filename2) if getattr(e, "filename2", None) is not None else where
        return f"{target} cannot be written or replaced ({e.strerror}: another user's, or read-only)"
    if e.errno == errno.EISDIR:
        # a folder under an output's name: the rename of the finished file onto it
        # names the temporary file first and the output second
        target = short_path(e.filename2) if getattr(e, "filename2", None) is not None else where
        return f"{target} is a folder; an output file of that name cannot be written"
    return None


#: Longest path an error line quotes whole; a longer one keeps its head and its tail.
SHORT_PATH_CHARS = 200


def short_path(path) -> str:
    """``path`` as an error line quotes it: whole up to :data:`SHORT_PATH_CHARS`, else its
    first 80 and last 100 characters around an ellipsis (a 4 kB path made a 4175-character
    line: hostile pass 24)."""
    text = os.fsdecode(path) if isinstance(path, bytes) else str(path)
    return text if len(text) <= SHORT_PATH_CHARS else f"{text[:80]}...{text[-100:]}"


def folder_name(path: str | Path) -> str:
    """The name of the file or folder ``path`` stands for: ``.`` and ``..`` (whose
    ``Path.name`` is empty or ``..``) are named after the folder they resolve to
    (``/`` itself: ``"root"``). Dataset names and default output folders take it, so
    ``--dataset .`` is never written ``runs/-isam2``."""
    path = Path(path)
    if path.name not in ("", ".."):
        return path.name
    return Path(os.path.abspath(path)).name or "root"


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``; moved over ``path`` when the block ends
    without an exception, deleted otherwise.

    For writers that want a file name (``np.savez``, matplotlib). A symbolic link is
    written through (its target replaced, the link kept), as ``open`` would: the link
    itself was replaced by a regular file (nineteenth hostile pass)."""
    path = through_links(path)
    tmp_path = temporary_beside(path)
    try:
        yield tmp_path
        move_into_place(tmp_path, path)
    except OSError as e:
        tmp_path.unlink(missing_ok=True)
        if e.filename is None:  # a write's (a full disk, a size limit): the output it was for
            e.filename = str(path)
        raise
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def through_links(path: str | Path) -> Path:
    """``path``, or the file it names through symbolic links (which need not exist yet)."""
    return Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)


def temporary_beside(path: Path) -> Path:
    """A new empty hidden file in ``path``'s folder (same file system, so the rename
    is atomic) with ``path``'s suffix (matplotlib and numpy choose the format from
    it). Its name is short whatever ``path``'s length: a 250-byte output name plus a
    suffix would pass the 255-byte limit only after the work is done."""
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= MAX_SUFFIX_BYTES else ""
    fd, tmp = tempfile.mkstemp(prefix=".gs-", suffix=".part" + suffix, dir=path.parent)
    os.close(fd)
    return Path(tmp)


def move_into_place(tmp: Path, path: Path) -> None:
    """Move the finished temporary ``tmp`` (:func:`temporary_beside`) over ``path``.

    mkstemp creates the file 0600; outputs get the usual umask-based mode."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


@contextmanager
def replacing_all(paths: list[Path]) -> Iterator[list[Path]]:
    """Temporary paths beside each of ``paths``, moved over them in order when the
    block ends without an exception, all deleted otherwise.

    Nothing is replaced until every file is written, so a full disk or a signal
    while writing leaves the old set whole. The last path marks the set complete
    (``map.json``): it is removed before the first move, so a cut between the
    moves leaves a set that says it is incomplete, never old and new mixed."""
    paths = [through_links(p) for p in paths]
    tmps: list[Path] = []
    try:
        for p in paths:
            tmps.append(temporary_beside(p))
        yield list(tmps)
        paths[-1].unlink(missing_ok=True)
        for tmp, p in zip(tmps, paths, strict=True):
            move_into_place(tmp, p)
    except BaseException:
        for tmp in tmps:
            tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_open(path: str | Path, mode: str = "w", **kwargs):
    """``open(path, mode)`` for writing, through :func:`replacing`."""
    if not any(c in mode for c in "wx"):
        raise ValueError(f"atomic_open writes whole files; mode {mode!r}")
    with replacing(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())


@functools.cache
def _umask() -> int:
    """The process umask, read once: Linux states it in /proc; elsewhere setting it
    back and forth is the only way (a moment in which another thread's new file
    would get the wrong mode, hence once)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_output_dir(path: str | Path, flag: str = "--out", files: Iterable[str] = ()) -> Path:
    """Refuse, before any work, an output folder that cannot be written: an
    existing file, a folder without write permission, a parent that is a file,
    a symbolic link (it or a parent) to nothing, or a folder in it under the name
    of one of the ``files`` the command writes.

    Creates nothing (a refused run leaves no trace); raises ConfigError.
    """
    path = Path(path)
    check_name_lengths(path, flag)
    longest = max(files, key=lambda n: len(os.fsencode(n)), default=None)
    if longest is not None:  # the folder fits, its files would not (hostile pass 24)
        size = len(os.fsencode(str(path / longest)))
        if size > PATH_MAX_BYTES:
            raise ConfigError(
                f"{flag}: its file {longest} would have a path of {size} bytes; systems take at most "
                f"{PATH_MAX_BYTES}"
            )
    for p in (path, *path.parents):  # a link to nothing cannot be made into a folder
        if p.is_symlink() and not p.exists():
            raise ConfigError(
                f"{flag} {path}: {p} is a symbolic link to {os.readlink(p)}, which does not exist"
            )
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path} is an existing file, not a folder")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"{flag} {path}: {existing} is a file, not a folder")
    _check_writable(existing, flag, path)
    check_no_folder_at(path, files, flag)
    return path


def check_no_folder_at(folder: str | Path, names: Iterable[str], flag: str = "--out") -> None:
    """Refuse a folder in ``folder`` under the name of a file the command will write
    there (the final rename onto it fails with EISDIR, after the work)."""
    for name in sorted(names):
        if (Path(folder) / name).is_dir():
            raise ConfigError(
                f"{flag} {folder}: {name} there is a folder; this command writes a file of that name"
            )
        check_special_file(Path(folder) / name, flag)


def names_a_folder(text: str) -> bool:
    """Whether a path as typed ends in a slash: a folder, which ``Path()`` forgets."""
    return text.endswith(("/", os.sep))


def check_output_file(path: str | Path, flag: str = "--out") -> Path:
    """Refuse, before any work, an output file that cannot be written: an existing
    folder, a parent that is a file, or a folder without write permission.

    Creates nothing; raises ConfigError.
    """
    if isinstance(path, str) and names_a_folder(path):  # Path() drops the slash
        raise ConfigError(f"{flag} {path} names a folder (it ends in a slash); give a file name")
    if str(path) == "-":  # stdout, by the usual convention: not a file written whole
        raise ConfigError(f"{flag} -: writing to stdout is not supported; give a file name")
    path = Path(path)
    check_name_lengths(path, flag)
    if path.is_dir():
        raise ConfigError(f"{flag} {path} is a folder; give a file name")
    check_special_file(path, flag)
    check_output_dir(path.parent if str(path.parent) else Path("."), flag)
    return path


def check_special_file(path: str | Path, flag: str = "--out") -> None:
    """Refuse an output that is a device, pipe or socket (``/dev/stdout``, a FIFO): the
    output is written beside it and moved into place, which replaced the pipe with a
    regular file, unsaid (hostile pass 18)."""
    if _links_into_proc(path):
        raise ConfigError(
            f"{flag} {path} is a stream of this process (a link into /proc: /dev/stdout), not "
            "a file it can write whole; give a file name"
        )
    try:
        mode = os.stat(path).st_mode
    except OSError:  # not there yet (or a dangling link, written through as open would)
        return
    if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        raise ConfigError(
            f"{flag} {path} is not a regular file (a device, pipe or socket): the output is "
            "written beside it and moved over it, so give a file name"
        )


def _links_into_proc(path: str | Path) -> bool:
    """Whether ``path`` or a link on the way to its file points into ``/proc`` (``/dev/stdout``
    -> ``/proc/self/fd/1``): with stdout redirected to a file the link passed the device test,
    and the output was written beside ``/dev/stdout`` and moved over it (the system's
    link became a regular file, the output never reached stdout: nineteenth hostile pass)."""
    seen = 0
    current = os.path.abspath(path)
    while os.path.islink(current) and seen < 40:  # (40: the kernel's own limit on a chain)
        if current.startswith("/proc/"):
            return True
        target = os.readlink(current)
        current = os.path.normpath(os.path.join(os.path.dirname(current), target))
        seen += 1
    return current.startswith("/proc/")


def _check_writable(folder: Path, flag: str, shown: Path) -> None:
    """Probe ``folder`` by creating a file in it (permissions alone miss read-only
    mounts and ignore root's rights)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".graphslam-probe.", dir=folder)
    except OSError as e:
        raise ConfigError(f"{flag} {shown}: cannot write in {folder} ({e.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def check_name_lengths(path: str | Path, flag: str) -> None:
    """Refuse, before any work, an empty path (an unset shell variable: ``Path("")`` is
    the current folder), a path over :data:`PATH_MAX_BYTES` or with a name over
    :data:`NAME_MAX_BYTES` (the system's answer, ENAMETOOLONG, would come as a
    traceback, or after the work)."""
    if isinstance(path, str) and not path.strip():
        raise ConfigError(f"{flag}: an empty path (an unset shell variable?); name a file or folder")
    size = len(os.fsencode(str(path)))
    if size > PATH_MAX_BYTES:
        raise ConfigError(f"{flag}: the path is {size} bytes; systems take at most {PATH_MAX_BYTES}")
    for part in Path(path).parts:
        size = len(os.fsencode(part))
        if size > NAME_MAX_BYTES:
            raise ConfigError(
                f"{flag}: the name {part[:24]}... is {size} bytes; file systems take at most {NAME_MAX_BYTES}"
            )


def check_distinct_outputs(outputs: dict[str, str | Path | None]) -> None:
    """Refuse two options naming the same output file (``{flag: path}``; None skipped):
    the second write would replace the first."""
    seen: dict[Path, str] = {}
    for flag, path in outputs.items():
        if path is None:
            continue
        key = Path(path).resolve()
        if key in seen:
            raise ConfigError(f"{seen[key]} and {flag} name the same file ({path}); give each its own")
        seen[key] = flag


def check_not_inputs(
    outputs: list[tuple[str, str | Path | None]], inputs: dict[str, str | Path | None]
) -> None:
    """Refuse, before any work, an output file that is one of the command's input files
    (``(what, path)`` pairs and ``{what: path}``, None skipped; links followed): writing
    it, or removing it as an earlier run's output, would destroy the input."""
    files: dict[Path, str] = {}
    for what, path in inputs.items():
        if path is not None and Path(path).is_file():
            files.setdefault(Path(path).resolve(), what)
    for what, path in outputs:
        source = None if path is None else files.get(Path(path).resolve())
        if source is not None:
            raise ConfigError(
                f"{what} {path} is the input {source}: this command would write over it or remove "
                "it; move the input or choose another output"
            )


def inside_folder(folder: str | Path, name: str | Path) -> Path | None:
    """``folder / name`` when it stays inside ``folder``, None when it leaves it
    (``../x``, an absolute path): a data set or a map names only its own files.

    Checked on the names (``..`` folded), not by resolving symbolic links: a data set
    may keep its images behind a link to another disk, and whoever can place a link
    in the folder could as well place the file."""
    folder = Path(folder)
    path = folder / name
    base = os.path.normpath(os.path.abspath(folder))
    full = os.path.normpath(os.path.abspath(path))
    if Path(full).is_relative_to(base) and full != base:
        return path
    return None
