"""Writers (and readers, for checks) of a SLAM run's outputs.

- Trajectories in the TUM RGB-D format (``t x y z qx qy qz qw``) and the KITTI odometry
  format (12 numbers a line: the 3x4 matrix ``[R | t]`` row-major), so standard tools such as
  ``evo`` read them. A planar pose (x, y, phi) is embedded in SE(3) as a rotation ``phi``
  about z at height 0.
- The map with its full covariance as ``.npz`` (``robot``, ``landmarks``, ``landmark_ids``,
  ``covariance``).
- Run statistics as JSON.
- A run's checkpoint (``dcslam run --checkpoint``): any picklable value, such as
  :class:`~dcslam.pipeline.PipelineProgress`, behind a header that marks the file as one.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import warnings
from typing import Any, Dict, Optional, Tuple, Union

import numpy as np

from .slam import Estimate

__all__ = [
    "write_tum",
    "read_tum",
    "write_kitti",
    "read_kitti",
    "save_map",
    "load_map",
    "write_stats_json",
    "write_run_checkpoint",
    "read_run_checkpoint",
    "pose_to_se3",
    "yaw_quaternion",
]

PathLike = Union[str, "os.PathLike[str]"]


def _poses(poses) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must be (k, 3) x, y, phi; got shape {poses.shape}")
    return poses


def yaw_quaternion(phi) -> np.ndarray:
    """(k, 4) unit quaternions (qx, qy, qz, qw) of rotations by ``phi`` about z."""
    half = np.asarray(phi, dtype=float) / 2.0
    zeros = np.zeros_like(half)
    return np.column_stack([zeros, zeros, np.sin(half), np.cos(half)])


def pose_to_se3(poses) -> np.ndarray:
    """(k, 4, 4) homogeneous transforms of planar poses (x, y, phi): rotation about z, z = 0."""
    poses = _poses(poses)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    transforms = np.zeros((len(poses), 4, 4))
    transforms[:, 0, 0], transforms[:, 0, 1], transforms[:, 0, 3] = c, -s, poses[:, 0]
    transforms[:, 1, 0], transforms[:, 1, 1], transforms[:, 1, 3] = s, c, poses[:, 1]
    transforms[:, 2, 2] = transforms[:, 3, 3] = 1.0
    return transforms


def _rows(path: PathLike, columns: int, format_name: str) -> np.ndarray:
    """The numbers of a trajectory file, ``columns`` a line; (0, columns) for a file without
    poses (e.g. a map-refit trajectory where no step saw enough mapped landmarks)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "loadtxt: input contained no data")
        rows = np.loadtxt(path, ndmin=2)
    if rows.size == 0:
        return np.zeros((0, columns))
    if rows.shape[1] != columns:
        raise ValueError(f"{os.fspath(path)}: {format_name} lines have {columns} numbers, found {rows.shape[1]}")
    return rows


def write_tum(path: PathLike, timestamps, poses) -> None:
    """Writes ``t x y z qx qy qz qw`` per pose (z = 0, yaw quaternion)."""
    poses = _poses(poses)
    timestamps = np.asarray(timestamps, dtype=float).reshape(-1)
    if len(timestamps) != len(poses):
        raise ValueError(f"write_tum: {len(timestamps)} timestamps for {len(poses)} poses")
    rows = np.column_stack([timestamps, poses[:, :2], np.zeros(len(poses)), yaw_quaternion(poses[:, 2])])
    np.savetxt(path, rows, fmt="%.9f", header="t x y z qx qy qz qw")


def read_tum(path: PathLike) -> Tuple[np.ndarray, np.ndarray]:
    """Reads a TUM trajectory of planar poses; returns (timestamps (k,), poses (k, 3)).

    The heading is the quaternion's rotation about z (tilt, if any, is ignored).
    """
    rows = _rows(path, 8, "TUM")
    qx, qy, qz, qw = rows[:, 4:].T
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy**2 + qz**2))
    return rows[:, 0], np.column_stack([rows[:, 1], rows[:, 2], yaw])


def write_kitti(path: PathLike, poses) -> None:
    """Writes the 3x4 matrix ``[R | t]`` of each pose row-major, 12 numbers a line."""
    transforms = pose_to_se3(poses)
    np.savetxt(path, transforms[:, :3, :].reshape(len(transforms), 12), fmt="%.9e")


def read_kitti(path: PathLike) -> np.ndarray:
    """Reads a KITTI trajectory of planar poses; returns (k, 3) x, y, phi."""
    rows = _rows(path, 12, "KITTI")
    matrices = rows.reshape(-1, 3, 4)
    return np.column_stack([matrices[:, 0, 3], matrices[:, 1, 3], np.arctan2(matrices[:, 1, 0], matrices[:, 0, 0])])


def save_map(path: PathLike, estimate: Estimate) -> None:
    """Saves the map as ``.npz``: robot (3,), landmarks (n, 2), landmark_ids (n,),
    past_poses (m, 3), past_pose_ids (m,), covariance (3 + 2n + 3m, 3 + 2n + 3m) (the joint
    one: :attr:`Estimate.joint_covariance`)."""
    np.savez_compressed(path, robot=estimate.robot, landmarks=estimate.landmarks,
                        landmark_ids=estimate.landmark_ids, past_poses=estimate.past_poses,
                        past_pose_ids=estimate.past_pose_ids,
                        covariance=estimate.joint_covariance)


def load_map(path: PathLike) -> Estimate:
    """Reads a map written by :func:`save_map` (also one saved before past poses existed,
    without ``past_poses``)."""
    with np.load(path) as data:
        values = {"robot": data["robot"], "landmarks": data["landmarks"],
                  "landmark_ids": data["landmark_ids"], "joint_covariance": data["covariance"]}
        if "past_poses" in data:
            values.update(past_poses=data["past_poses"], past_pose_ids=data["past_pose_ids"])
        return Estimate._from_core(values)


def _plain(value: Any) -> Any:
    """numpy scalars and arrays -> built-in types, recursively, for ``json``."""
    if isinstance(value, dict):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_stats_json(path: PathLike, result, extra: Optional[Dict[str, Any]] = None) -> None:
    """Writes a :class:`~dcslam.pipeline.PipelineResult`'s numbers as JSON.

    Keys: ``summary`` (totals, map size, joins, association counts), ``config``,
    ``per_step`` (``t``, ``seconds``, ``num_features``, ``measurements``, ``paired``,
    ``new_features``, ``rejected``), ``joins`` (D&C join events), ``fold_joins`` (the joins of
    D&C's final fold, ``DCSlamStats.fold_joins``), ``counters``, and the entries of ``extra``
    (e.g. ``gps_alignment``).
    """
    stats = result.stats
    document = {
        "summary": result.summary(),
        "config": result.config.to_dict(),
        "per_step": {
            "t": result.timestamps,
            "seconds": stats.step_seconds,
            "num_features": stats.num_features,
            "measurements": stats.measurements,
            "paired": stats.paired,
            "new_features": stats.new_features,
            "rejected": stats.rejected,
        },
        "joins": result.joins,
        "fold_joins": result.fold_joins,
        "counters": stats.counters,
        **(extra or {}),
    }
    with open(path, "w", encoding="utf-8") as out:
        json.dump(_plain(document), out, indent=1)
        out.write("\n")


# The first line of a checkpoint file; the number is the layout of what follows: the SHA-256
# of the pickle (hex, one line), then the pickle.
_CHECKPOINT_HEADER = b"dcslam run checkpoint 1\n"


def write_run_checkpoint(path: PathLike, value: Any) -> None:
    """Pickles ``value`` into ``path`` behind a header line and the pickle's SHA-256. The file
    is written beside ``path`` and renamed over it, so that a run killed while writing leaves
    the previous checkpoint whole."""
    payload = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    path = os.fspath(path)
    temporary = path + ".partial"
    with open(temporary, "wb") as out:
        out.write(_CHECKPOINT_HEADER + hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload)
    os.replace(temporary, path)


def read_run_checkpoint(path: PathLike) -> Any:
    """Reads what :func:`write_run_checkpoint` wrote. A checkpoint is a pickle: read only
    files you trust (your own runs'), as with any pickle; the checksum guards against damage,
    not against a forged file.

    Raises:
        OSError: the file cannot be read (e.g. it does not exist).
        ValueError: the file is not a dcslam checkpoint, is of another layout, or is damaged
            (truncated, or any byte changed); the message names the file.
    """
    name = os.fspath(path)
    with open(path, "rb") as file:
        header = file.readline()
        if header != _CHECKPOINT_HEADER:
            if header.startswith(_CHECKPOINT_HEADER[:-3]):
                raise ValueError(f"{name}: a dcslam checkpoint of another layout "
                                 f"({header.strip().decode(errors='replace')!r}); this version reads "
                                 f"{_CHECKPOINT_HEADER.strip().decode()!r}")
            raise ValueError(f"{name}: not a dcslam checkpoint")
        digest = file.readline().strip()
        payload = file.read()
    if hashlib.sha256(payload).hexdigest().encode() != digest:
        raise ValueError(f"{name}: damaged checkpoint (truncated or changed: its checksum does not match)")
    try:
        return pickle.loads(payload)
    except Exception as error:  # unpickling raises many types; after the checksum, e.g. a missing module
        raise ValueError(f"{name}: cannot load the checkpoint ({type(error).__name__}: {error})") from None
