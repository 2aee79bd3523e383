"""A run's inputs packed in flat arrays: what the datasets and the simulator hold and what
:meth:`dcslam.SlamFilter.run_batch` takes (docs/api.md, "Batch runs"); and the one
:class:`Step` type that every dataset's and the simulator's ``steps`` are views of them as.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Callable, Iterator, Optional, Union, overload

import numpy as np

__all__ = ["PackedSteps", "Step", "Steps"]


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


class Step:
    """One filter step: predict with ``u`` (3,) and ``Q`` (3, 3), then update with ``z``
    (m, 2) and ``R`` (m, 2, 2).

    ``index`` is the step's place in its run; ``landmark_ids`` (m,) int64 the landmark each
    measurement is of (-1: clutter) where the source knows it: the simulator's truth, an
    iSAM file's ids, MR.CLAM's subject numbers; None for Victoria Park. ``true_ids`` is the
    same array (the name docs/api.md gives a simulated step's ids). Victoria Park steps also
    have ``t`` (scan time, s) and ``diameters`` (m,), MR.CLAM steps ``t``, iSAM steps
    ``pose_id``. The arrays of a dataset's or a simulation's steps are read-only views.
    """

    __slots__ = ("u", "Q", "z", "R", "t", "diameters", "landmark_ids", "pose_id", "index")

    def __init__(self, u, Q, z, R, t=None, diameters=None, landmark_ids=None, pose_id=None, index=None):
        self.u, self.Q, self.z, self.R = u, Q, z, R
        self.t, self.diameters = t, diameters
        self.landmark_ids, self.pose_id = landmark_ids, pose_id
        self.index = index

    @property
    def true_ids(self):
        return self.landmark_ids

    def __repr__(self) -> str:
        where = "" if self.index is None else f"{self.index}, "
        when = f"t={self.t:.3f}, " if self.t is not None else ""
        return f"Step({where}{when}u={np.array2string(np.asarray(self.u), precision=4)}, m={len(self.z)})"


class Steps(Sequence):
    """A run's steps as a sequence (``len``, indexing, negative too, slicing, iteration), each
    :class:`Step` built on demand by ``make_step(k, rows)`` from its arrays, ``rows`` the slice
    of the measurement arrays that ``offsets`` gives step k. ``packed_steps()`` is the owner's:
    :meth:`dcslam.SlamFilter.run` uses the arrays in place."""

    def __init__(self, offsets: np.ndarray, make_step: Callable[[int, slice], Step],
                 packed_steps: Callable[[], PackedSteps]):
        self._offsets = offsets
        self._make_step = make_step
        self._count = len(offsets) - 1
        self.packed_steps = packed_steps

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, index: int) -> Step: ...

    @overload
    def __getitem__(self, index: slice) -> list: ...

    def __getitem__(self, index: Union[int, slice]):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(self._count))]
        k = int(index)
        if k < 0:
            k += self._count
        if not 0 <= k < self._count:
            raise IndexError(f"step {index} out of range for {self._count} steps")
        return self._make_step(k, slice(int(self._offsets[k]), int(self._offsets[k + 1])))

    def __iter__(self) -> Iterator[Step]:
        return (self[k] for k in range(self._count))
