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


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) smallest rotations turning directions `a` onto `b` (..., 3): a half turn about an
    axis across `a` where they are opposite."""
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-300)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-300)
    v, c = np.cross(a, b), np.sum(a * b, axis=-1)
    k = np.zeros(a.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    opposite = c < -1 + 1e-9
    scale = np.where(opposite, 0.0, 1.0 / np.maximum(1.0 + c, 1e-9))[..., None, None]
    out = np.eye(3) + k + k @ k * scale
    if opposite.any():
        helper = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
        n = np.cross(a, helper)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        half = 2 * n[..., :, None] * n[..., None, :] - np.eye(3)
        out = np.where(opposite[..., None, None], half, out)
    return out
