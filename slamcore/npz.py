"""Refuse a ``.npz`` member whose header declares more data than the file can hold.

``np.load`` allocates the array its header declares before reading any data:
a few hundred bytes declaring 10^9 float64 ask for 7.45 GiB. The bound here is
what the zip member could really produce: its declared uncompressed size, and
at most :data:`MAX_DEFLATE_RATIO` times its compressed size (deflate cannot do
better), so no valid file is refused.
"""

from __future__ import annotations

import math
import zipfile

import numpy as np

from slamcore.errors import InputError, quote

#: Deflate's best ratio (258-byte matches in 2 bits, about 1032:1), rounded up.
MAX_DEFLATE_RATIO = 1100


def check_npz_sizes(source, path) -> None:
    """InputError naming ``path`` if a ``.npy`` member of the zip ``source`` (a path
    or a binary file object) declares more bytes than it could hold. Damage of the
    zip or of a header raises zipfile.BadZipFile or ValueError, as ``np.load`` does."""
    with zipfile.ZipFile(source) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                else:  # 2.0 and 3.0 differ only in the header's text encoding
                    shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
            declared = math.prod(shape) * dtype.itemsize
            bound = min(info.file_size, MAX_DEFLATE_RATIO * info.compress_size)
            if declared > bound:
                raise InputError(
                    f"array {quote(info.filename[:-4])} declares shape {shape} of "
                    f"{dtype} ({declared} bytes), more than its {bound}-byte "
                    "zip member can hold",
                    path,
                )
