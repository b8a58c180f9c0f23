"""Refuse input paths that are neither a regular file nor a folder.

A FIFO blocks the reader forever and ``/dev/zero`` never ends: reading either
hangs or fills memory, so such paths are refused before anything opens them.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from slamcore.errors import InputError, LocatedError


def _kind(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a special file"


def check_input_path(
    path: str | Path, what: str, folder_ok: bool = False, error: type[LocatedError] = InputError
) -> None:
    """Raise ``error`` (one line naming ``path``) unless ``path`` is a regular
    file, or a folder when ``folder_ok``; a missing path says "not found"."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise error(f"{what} not found", path) from None
    except (OSError, ValueError) as e:  # ValueError: a NUL byte in the name
        raise error(f"cannot read {what}: {getattr(e, 'strerror', None) or e}", path) from None
    if stat.S_ISREG(mode) or (folder_ok and stat.S_ISDIR(mode)):
        return
    kind = "a folder" if stat.S_ISDIR(mode) else _kind(mode)
    expected = "a file or a folder" if folder_ok else "a file"
    raise error(f"{what} is {kind}, not {expected}", path)


def check_plain_text(path, error=InputError) -> None:
    """``error`` naming ``path`` when its first bytes say it is text the readers cannot
    take as it is: UTF-16 (PowerShell's ``>`` writes it; it was "unknown tag
    'V\\x00E\\x00...'" or a decoding error) or gzip-compressed (a ``.g2o.gz``). Nothing
    for an unreadable file: the reader says that itself."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return
    if head[:2] in (b"\xff\xfe", b"\xfe\xff") or (
        len(head) >= 8 and head[1::2].count(0) >= len(head[1::2]) // 2 and head[0::2].count(0) == 0
    ):
        raise error("UTF-16 text (as Windows tools write it): save it as UTF-8", path)
    if head[:2] == b"\x1f\x8b":
        raise error("gzip-compressed: decompress it first (gunzip)", path)


def files_below(folder: str | Path) -> list[Path]:
    """Every regular file in ``folder`` and its sub-folders, following symbolic links (an
    image folder linked in from elsewhere is read through its link; ``Path.rglob`` does not
    follow linked folders before Python 3.13), each linked folder once (a link back up the
    tree would never end), sorted.

    Raises:
        OSError: a sub-folder or file that cannot be read.
    """

    def refused(e: OSError) -> None:
        raise e

    out, seen = [], set()
    for root, dirs, names in os.walk(folder, followlinks=True, onerror=refused):
        here = os.path.realpath(root)
        if here in seen:
            dirs[:] = []
            continue
        seen.add(here)
        out += [p for p in (Path(root) / n for n in names) if p.is_file()]
    return sorted(out)
