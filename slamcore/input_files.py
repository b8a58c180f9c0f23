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
