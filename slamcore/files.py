"""Files written whole or not at all, and output paths checked before a run.

A writer that is cut (a signal, a full disk, a crash) must leave either the old
complete file or the new complete one, never half of the new one: every output
is written to a temporary file in the same folder and moved over the target
with :func:`os.replace`, which is atomic on POSIX and Windows.
"""

from __future__ import annotations

import functools
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from slamcore.errors import ConfigError


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``; moved over ``path`` when the block ends
    without an exception, deleted otherwise.

    For writers that want a file name (``np.savez``, matplotlib)."""
    path = Path(path)
    # hidden, same folder (same file system, so the rename is atomic), same
    # suffix (matplotlib and numpy choose the format from it)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.part-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates the file 0600; outputs get the usual umask-based mode
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
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


def check_output_dir(path: str | Path, flag: str = "--out") -> Path:
    """Refuse, before any work, an output folder that cannot be written: an
    existing file, a folder without write permission, or a parent that is a file.

    Creates nothing (a refused run leaves no trace); raises ConfigError.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path} is an existing file, not a folder")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"{flag} {path}: {existing} is a file, not a folder")
    _check_writable(existing, flag, path)
    return path


def check_output_file(path: str | Path, flag: str = "--out") -> Path:
    """Refuse, before any work, an output file that cannot be written: an existing
    folder, a parent that is a file, or a folder without write permission.

    Creates nothing; raises ConfigError.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{flag} {path} is a folder; give a file name")
    check_output_dir(path.parent if str(path.parent) else Path("."), flag)
    return path


def _check_writable(folder: Path, flag: str, shown: Path) -> None:
    """Probe ``folder`` by creating a file in it (permissions alone miss read-only
    mounts and ignore root's rights)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".graphslam-probe.", dir=folder)
    except OSError as e:
        raise ConfigError(f"{flag} {shown}: cannot write in {folder} ({e.strerror})") from None
    os.close(fd)
    os.unlink(probe)
