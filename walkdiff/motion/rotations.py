"""Rotation conversions: thin wrappers over roma, the one place that knows its conventions.

Euler orders are BVH channel orders: 'ZYX' means the file lists Zrotation, Yrotation, Xrotation and the
rotation is R = R_Z(a0) @ R_Y(a1) @ R_X(a2), i.e. intrinsic axes, which roma writes in upper case.
Orders may be shorter than three axes (a joint with only some rotation channels).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import roma
import torch


@contextmanager
def _one_thread() -> Iterator[None]:
    """Run torch on one thread: the many small element-wise ops of an Euler conversion gain nothing from
    intra-op threads, and on busy cores they lose badly (reading the Xia set took 33 s instead of 4.5 s)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """(..., len(order)) angles in degrees -> (..., 3, 3) float64 rotation matrices."""
    angles = torch.as_tensor(np.asarray(angles_deg, dtype=np.float64))
    with _one_thread():
        return roma.euler_to_rotmat(order.upper(), angles, degrees=True).numpy()


def matrix_to_euler(matrices: np.ndarray, order: str) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., len(order)) angles in degrees.

    For an order of fewer than three axes the missing axes are appended (applied innermost) and dropped
    afterwards: exact when the rotation only turns about the given axes, a projection otherwise.
    """
    order = order.upper()
    full = order + "".join(axis for axis in "XYZ" if axis not in order)
    m = torch.as_tensor(np.asarray(matrices, dtype=np.float64))
    with _one_thread():
        return roma.rotmat_to_euler(full, m, degrees=True).numpy()[..., : len(order)]


def matrix_to_6d(m: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first column followed by the second column."""
    return m[..., :, :2].transpose(-1, -2).reshape(*m.shape[:-2], 6)


def sixd_to_matrix(x: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3) rotation matrices by Gram-Schmidt (any 6 numbers give a valid rotation)."""
    columns = x.reshape(*x.shape[:-1], 2, 3).transpose(-1, -2)
    return roma.special_gramschmidt(columns)


def matrix_to_quaternion(m: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 4) unit quaternions in roma's XYZW order."""
    return roma.rotmat_to_unitquat(m)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) XYZW quaternions (normalised here) -> (..., 3, 3)."""
    return roma.unitquat_to_rotmat(roma.quat_normalize(q))
