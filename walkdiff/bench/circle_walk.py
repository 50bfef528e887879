"""A walk bent into a circle: the benchmark's turning source made from a real straight walk.

Real turning clips turn once (Xia's turn about 90 degrees in a second); a character walking round in
a circle turns all the time, its feet set wider on the outside of each step. `circled` turns a clip's
whole body about the vertical as it goes, by its distance walked over the radius, so that its path
bends into an arc of that radius. Each frame's turn pivots about the feet then planted (the mean of
the contact joints in contact, by the clip's own profile; the body's root when none is), as a
walker's body turns over its standing foot: a planted foot stays where it is, only a foot in double
support turns a little about the point between both.
"""

from __future__ import annotations

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import contact_state
from walkdiff.motion.skeleton import Motion

WALKING_SPEED_M_S = 0.5  # a clip whose body goes on average this fast over the ground walks (or runs)


def travels(motion: Motion) -> bool:
    """Whether the clip's body goes somewhere: its root's horizontal path at WALKING_SPEED_M_S or more
    on average (a walk or a run, not a punch or a jump on the spot)."""
    profile = SkeletonProfile.detect(motion)
    points = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)
    root = (points[:, profile.root_index] @ profile.turn.T)[:, [0, 2]]
    path = np.linalg.norm(np.diff(root, axis=0), axis=1).sum() * profile.metres_per_unit
    return path / max(motion.num_frames - 1, 1) * motion.fps >= WALKING_SPEED_M_S


def _yaw(angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) turns by `angle` (F,) about +Y (canonical up)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((len(angle), 3, 3))
    out[:, 0, 0], out[:, 0, 2], out[:, 1, 1], out[:, 2, 0], out[:, 2, 2] = c, s, 1.0, -s, c
    return out


def circled(motion: Motion, radius_m: float, sign: float = 1.0) -> Motion:
    """`motion` walking along an arc of `radius_m` metres instead of its own path: the same poses, the
    whole body turned about the vertical over its planted feet (`sign` +1 or -1: which way, right-handed
    about the up axis)."""
    if not radius_m > 0:
        raise WalkdiffError(f"circled: radius {radius_m}: expected a positive number of metres")
    profile = SkeletonProfile.detect(motion)
    turn = profile.turn  # file axes -> canonical (Y up)
    points = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents) @ turn.T
    feet = [motion.skeleton.index(n) for n in profile.contacts.joints]
    low, slow = contact_state(points[:, feet], motion.fps, profile.contacts)
    planted = (low & slow).astype(np.float64)  # (F, 4)
    count = planted.sum(axis=1)
    pivot = np.einsum("fk,fkc->fc", planted, points[:, feet]) / np.maximum(count, 1)[:, None]
    root = points[:, profile.root_index]
    pivot = np.where((count > 0)[:, None], pivot, root)
    pivot[:, 1] = 0.0
    walked = np.concatenate([[0.0], np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1)])
    radius = radius_m / profile.metres_per_unit
    angle = np.cumsum(walked) / radius * np.sign(sign)
    yaw = _yaw(angle)
    # x' = yaw_t x + shift_t; the pivot q_t stays put: shift_t - shift_t-1 = -(yaw_t - yaw_t-1) q_t.
    steps = np.einsum("fij,fj->fi", yaw[1:] - yaw[:-1], pivot[1:])
    shift = np.concatenate([np.zeros((1, 3)), -np.cumsum(steps, axis=0)])
    in_file = turn.T @ yaw @ turn  # the same turns in the file's axes
    rotations, positions = motion.rotations.copy(), motion.positions.copy()
    rotations[:, 0] = in_file @ motion.rotations[:, 0]
    positions[:, 0] = np.einsum("fij,fj->fi", in_file, motion.positions[:, 0]) + shift @ turn
    return Motion(motion.skeleton, rotations, positions, motion.frame_time)
