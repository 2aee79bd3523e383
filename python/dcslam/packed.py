"""A run's inputs packed in flat arrays: what the datasets and the simulator hold and what
:meth:`dcslam.SlamFilter.run_batch` takes (docs/api.md, "Batch runs")."""

from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

__all__ = ["PackedSteps"]


@dataclasses.dataclass(frozen=True)
class PackedSteps:
    """N steps with M measurements in all, as views of their owner's arrays (no copies).

    Attributes:
        u: (N, 3) relative motions x_{R(k-1) R(k)} (x, y in m; phi in rad).
        Q: (N, 3, 3) their covariances, or one (3, 3) for every step.
        z: (M, 2) every step's measurements in step order, (r [m], beta [rad]) or (x, y) [m].
        R: (M, 2, 2) their covariances, or one (2, 2) for every measurement.
        offsets: (N + 1,) int64; step k owns rows ``offsets[k]:offsets[k + 1]`` of z, R and
            landmark_ids.
        landmark_ids: (M,) int64 landmark of each measurement (-1: none), or None.
    """

    u: np.ndarray
    Q: np.ndarray
    z: np.ndarray
    R: np.ndarray
    offsets: np.ndarray
    landmark_ids: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.offsets) - 1
