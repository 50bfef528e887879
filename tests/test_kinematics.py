"""Forward kinematics against pybvh (an independent implementation) and against hand-made skeletons."""

from __future__ import annotations

import math

import numpy as np
import pybvh
import pytest
import roma
import torch

from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.kinematics import forward_kinematics, motion_world_positions

# A walk, a turn, a run, a jump and a kick: different poses and root paths.
XIA_CLIPS = ["neutral_01_000", "old_03_000", "proud_13_000", "angry_16_000", "sexy_22_000"]


@pytest.mark.parametrize("name", XIA_CLIPS)
def test_fk_matches_pybvh_on_xia(xia_dir, name):
    path = xia_dir / f"{name}.bvh"
    ours = motion_world_positions(read_bvh(path))
    oracle = pybvh.read_bvh_file(path).joint_positions()  # (F, J, 3), same joint order as the file
    assert ours.dtype == np.float64
    assert ours.shape == oracle.shape
    assert np.abs(ours - oracle).max() < 1e-4


def _chain() -> tuple[list[int], torch.Tensor]:
    """Root with two branches: 0 -> 1 -> 2 and 0 -> 3."""
    parents = [-1, 0, 1, 0]
    offsets = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], dtype=torch.float64)
    return parents, offsets


def test_fk_by_hand():
    parents, offsets = _chain()
    rotations = torch.eye(3, dtype=torch.float64).repeat(4, 1, 1)
    rotations[1] = roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    positions = offsets.clone()
    positions[0] = torch.tensor([5.0, 0, 0])
    world, world_rot = forward_kinematics(rotations, positions, parents, return_rotations=True)
    # Joint 2's bone (+2 Y) is turned by joint 1's 90 degrees about Z to -2 X.
    expected = torch.tensor([[5.0, 0, 0], [6, 0, 0], [4, 0, 0], [5, 0, 3]], dtype=torch.float64)
    torch.testing.assert_close(world, expected)
    torch.testing.assert_close(world_rot[2], rotations[1])


def test_fk_batches_and_broadcasts_offsets():
    parents, offsets = _chain()
    rotations = roma.random_rotmat((2, 5, 4), dtype=torch.float64)
    batched = forward_kinematics(rotations, offsets, parents)  # (J, 3) offsets shared by every frame
    assert batched.shape == (2, 5, 4, 3)
    for b in range(2):
        for f in range(5):
            torch.testing.assert_close(batched[b, f], forward_kinematics(rotations[b, f], offsets, parents))


def test_fk_gradient():
    parents, offsets = _chain()
    rotations = roma.random_rotmat((3, 4), dtype=torch.float64).requires_grad_()
    positions = offsets.expand(3, 4, 3).clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda r, p: forward_kinematics(r, p, parents), (rotations, positions))
    # Joint 3 hangs off the root only: joints 1 and 2 cannot move it.
    forward_kinematics(rotations, positions, parents)[:, 3].sum().backward()
    assert rotations.grad[:, 0].abs().sum() > 0
    assert torch.all(rotations.grad[:, 1:3] == 0)


def test_fk_rejects_bad_input():
    rotations = torch.eye(3).repeat(3, 1, 1)
    with pytest.raises(ValueError, match="parents must precede"):
        forward_kinematics(rotations, torch.zeros(3, 3), [-1, 2, 0])
    with pytest.raises(ValueError, match="expected rotations"):
        forward_kinematics(rotations, torch.zeros(2, 3), [-1, 0, 1])
