"""Feature records and the detector protocol shared by every front end."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True, eq=False)
class Features:
    """Corners detected in one image.

    Attributes:
        xy_px: (N, 2) float64 pixel coordinates ``[u, v]`` (column, row).
        response: (N,) detector response (Harris R, ORB score...), float64.
        descriptors: (N, D) descriptors (uint8 for ORB's 32 bytes), or None.
        cell: (N,) int index of the tessellation cell each point won, or None.
        ready_time_s: when the points become readable by the processor (the
            simulated FPGA stream stamps this), or None for software detectors.
    """

    xy_px: np.ndarray
    response: np.ndarray
    descriptors: np.ndarray | None = None
    cell: np.ndarray | None = None
    ready_time_s: float | None = None

    def __len__(self) -> int:
        return int(self.xy_px.shape[0])


@runtime_checkable
class Detector(Protocol):
    """Anything that turns a greyscale image into :class:`Features`."""

    def detect(self, image: np.ndarray) -> Features:
        """``image``: (H, W) uint8 greyscale. Returns the detected features."""
        ...
