"""Forward kinematics: local joint rotations and translations -> world positions (and rotations).

One function for torch and numpy: batched over any leading dimensions, differentiable on torch
tensors (models put losses on joint positions), and on numpy arrays several times faster for the few
frames at a time a live controller poses. The joint loop relies on walkdiff's ordering convention (a
parent precedes its children), which makes one pass over the joints enough. Numpy arrays of one shape
take one batched product per tree level instead of one per joint: on a 75-joint rig a Python step per
joint costs more than the maths (the retargeter poses whole clips this way).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from walkdiff.motion.skeleton import Motion


def forward_kinematics(
    rotations: torch.Tensor | np.ndarray,
    positions: torch.Tensor | np.ndarray,
    parents: Sequence[int] | np.ndarray | torch.Tensor,
    return_rotations: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """World joint positions (..., J, 3) from local rotations (..., J, 3, 3) and translations (..., J, 3).

    `positions[..., j, :]` is joint j's translation in its parent's frame (for the root: its world
    position). Leading dimensions of `rotations` and `positions` broadcast against each other, so a
    (J, 3) offset table can drive a (B, F, J, 3, 3) batch of rotations. With `return_rotations` the
    world rotations (..., J, 3, 3) come back too. Numpy arrays in, numpy arrays out.
    """
    parents = [int(p) for p in parents]
    num_joints = len(parents)
    if rotations.shape[-3:] != (num_joints, 3, 3) or positions.shape[-2:] != (num_joints, 3):
        raise ValueError(
            f"expected rotations (..., {num_joints}, 3, 3) and positions (..., {num_joints}, 3), "
            f"got {tuple(rotations.shape)} and {tuple(positions.shape)}"
        )
    if isinstance(rotations, np.ndarray) and rotations.shape[:-3] == positions.shape[:-2]:
        world_pos, world_rot = _by_level(rotations, positions, parents)
        return (world_pos, world_rot) if return_rotations else world_pos
    world_rot: list[torch.Tensor] = []
    world_pos: list[torch.Tensor] = []
    for joint, parent in enumerate(parents):
        local_rot = rotations[..., joint, :, :]
        local_pos = positions[..., joint, :]
        if parent < 0:
            world_rot.append(local_rot)
            world_pos.append(local_pos)
            continue
        if parent >= joint:
            raise ValueError(f"joint {joint} has parent {parent}: parents must precede their children")
        parent_rot = world_rot[parent]
        world_rot.append(parent_rot @ local_rot)
        world_pos.append((parent_rot @ local_pos[..., None])[..., 0] + world_pos[parent])
    # Leading dimensions may differ between joints (the root's translation is per frame, an offset
    # table is not), so broadcast before stacking.
    numpy = isinstance(rotations, np.ndarray)
    shape = (np if numpy else torch).broadcast_shapes(rotations.shape[:-3], positions.shape[:-2])
    positions_out = _stacked(world_pos, shape, (3,))
    if not return_rotations:
        return positions_out
    return positions_out, _stacked(world_rot, shape, (3, 3))


def depth_levels(parents) -> list[np.ndarray]:
    """Joint indices grouped by depth in the tree, root level first: one batched step per level."""
    parents = np.asarray(parents)
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):
        if 0 <= p and p >= j:
            raise ValueError(f"joint {j} has parent {p}: parents must precede their children")
        depth[j] = 0 if p < 0 else depth[p] + 1
    return [np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1)]


def _by_level(rotations: np.ndarray, positions: np.ndarray, parents) -> tuple[np.ndarray, np.ndarray]:
    """Numpy world positions and rotations, one batched product per tree level."""
    parents = np.asarray(parents)
    world_rot, world_pos = np.empty_like(rotations), np.empty_like(positions)
    for level in depth_levels(parents):
        up = parents[level]
        if up[0] < 0:
            world_rot[..., level, :, :], world_pos[..., level, :] = (
                rotations[..., level, :, :],
                positions[..., level, :],
            )
            continue
        parent_rot = world_rot[..., up, :, :]
        world_rot[..., level, :, :] = parent_rot @ rotations[..., level, :, :]
        world_pos[..., level, :] = (
            world_pos[..., up, :] + (parent_rot @ positions[..., level, :, None])[..., 0]
        )
    return world_pos, world_rot


def _stacked(parts: list, shape: tuple[int, ...], tail: tuple[int, ...]):
    """Per-joint arrays or tensors broadcast to `shape` + `tail`, stacked on a joint axis before `tail`."""
    axis = -len(tail) - 1
    if isinstance(parts[0], np.ndarray):
        return np.stack([np.broadcast_to(x, (*shape, *tail)) for x in parts], axis=axis)
    return torch.stack([x.expand(*shape, *tail) for x in parts], dim=axis)


def motion_world_positions(motion: Motion) -> np.ndarray:
    """(F, J, 3) float64 world joint positions of a clip."""
    # torch.tensor copies: Motion arrays may be read-only views, which torch.from_numpy warns about.
    positions = forward_kinematics(
        torch.tensor(motion.rotations), torch.tensor(motion.positions), motion.skeleton.parents
    )
    return positions.numpy()
