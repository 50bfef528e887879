"""Feet that stay where they were put down, frame by frame as a live walker makes them (a foot lock).

`footfix.fix_feet` pins each contact of a finished clip to the mean of where it slid; a live walker has
no later frames to average over. Here a foot joint (heel or toe) that the walker's contact channels put
on the ground is held where it touched down: the first frame of a contact sets its anchor on the ground,
and while the contact lasts (and after it, until the joint has risen a contact height above where it
landed: a foot does not slide off its place as it is lifted) the ankle is moved along the ground by the
offset that puts the held joints back on their anchors (the mean offset when heel and toe both are), and
the leg reaches the moved ankle by `footfix`'s two-bone IK (hip and knee; the foot keeps its world
orientation). When the foot lifts off, the last offset fades out over `blend` frames so the leg does not
snap. An offset is never longer than `MAX_OFFSET` leg lengths: a contact the model holds longer than its
stride allows drags the anchor along with the body.

Clearance: a foot joint that is not held, lower than a contact height above where that joint lands
(a running mean of its landing heights), and moving along the ground faster than a foot on the ground
may (the profile's contact speed), is a swinging foot skimming the floor: its ankle is raised until the
joint is a contact height up, and let down over a few frames (`LIFT_FADE`) once it no longer skims.
On Xia's walker most of the frames that skated under `bench play` were such feet, not ones the walker
had planted (docs/live-control.md).

Only the rotation channels of the hips, knees and ankles of the frames it moves change; what the walker
feeds back to itself is its own frame, so the lock never changes the motion it goes on to make.
"""

from __future__ import annotations

import numpy as np
import torch

from walkdiff.motion.footfix import reach
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.profile_detection import CONTACT_HEIGHT
from walkdiff.motion.representation import yaw_matrix
from walkdiff.motion.rotations import matrix_to_6d, sixd_to_matrix

MAX_OFFSET = 0.25  # leg lengths an anchor may lie from where the model puts its foot
CONTACT = 0.5  # a contact channel above this puts the joint on the ground
BLEND = 6  # frames the offset fades out over after a foot lifts off
LIFT_FADE = 0.7  # a lifted foot that no longer skims comes down by 30% of its lift a frame, not at once


class FootLock:
    """The lock's state for N characters of one walker model (see the module docstring)."""

    def __init__(self, model, characters: int, blend: int = BLEND):
        skeleton, spec = model.skeleton, model.profile.contacts
        self.layout, self.parents, self.blend = model.layout, skeleton.parents, blend
        self.offsets = torch.from_numpy(skeleton.offsets).double()
        joints = [skeleton.index(name) for name in spec.joints]  # left heel, left toe, right heel, right toe
        self.feet = [joints[:2], joints[2:]]
        self.max_offset = MAX_OFFSET * spec.height_threshold / CONTACT_HEIGHT  # in the skeleton's units
        self.anchors = np.full((characters, 4, 2), np.nan)  # (x, z) each contact joint is held at
        self.landed = np.full((characters, 4), np.nan)  # the height it landed at
        self.height = spec.height_threshold
        self.offset = np.zeros((characters, 2, 2))  # the offset each foot's ankle got last frame
        self.fading = np.zeros((characters, 2), dtype=int)  # frames of fade left after a lift-off
        # Clearance: a free joint that skims the floor faster than a foot on the ground moves is lifted.
        self.speed, self.fps = spec.speed_threshold, model.spec["fps"]
        self.floor = np.full((characters, 4), np.nan)  # where each joint lands, a running mean
        self.previous = np.full((characters, 4, 2), np.nan)  # each joint's (x, z) a frame ago
        self.lifted = np.zeros((characters, 2))  # how far each foot's ankle was raised last frame

    def copy(self) -> FootLock:
        other = object.__new__(FootLock)
        other.__dict__ = dict(self.__dict__)
        for name in ("anchors", "landed", "offset", "fading", "floor", "previous", "lifted"):
            setattr(other, name, getattr(self, name).copy())
        return other

    def apply(self, raw: np.ndarray, position: np.ndarray, heading: np.ndarray) -> None:
        """Locks the feet of one frame of raw features (N, D) in place, the characters' roots at
        `position` (N, 2) facing `heading` (N,)."""
        layout = self.layout
        sixd = torch.from_numpy(raw[:, layout.rotations]).double().unflatten(-1, (layout.num_joints, 6))
        rotations = sixd_to_matrix(sixd)
        rotations[:, 0] = yaw_matrix(torch.from_numpy(heading).double()) @ rotations[:, 0]
        translations = self.offsets.expand(len(raw), -1, -1).clone()
        root = np.stack([position[:, 0], raw[:, layout.root_height.start], position[:, 1]], axis=-1)
        translations[:, 0] = torch.from_numpy(root)
        world, world_rot = forward_kinematics(rotations, translations, self.parents, return_rotations=True)
        world, world_rot = world.numpy(), world_rot.numpy()
        contacts = raw[:, layout.contacts] > CONTACT
        local = rotations.numpy()
        for side, (heel, toe) in enumerate(self.feet):
            feet = world[:, [heel, toe]]
            offset = self._offset(side, feet[..., [0, 2]], feet[..., 1], contacts[:, 2 * side : 2 * side + 2])
            lift = self._lift(side, feet[..., [0, 2]], feet[..., 1])
            moved = (np.abs(offset).sum(-1) > 0) | (lift > 0)
            if not moved.any():
                continue
            target = world[:, heel] + np.insert(offset, 1, lift, axis=-1)
            bent = reach(local, world, world_rot, self.parents, heel, target, moved)
            # Only the moved joints' channels: the others keep the walker's numbers (writing them again
            # would orthonormalise their 6D rotations, the same pose in other numbers).
            knee = int(self.parents[heel])
            for joint in (int(self.parents[knee]), knee, heel):
                start = layout.rotations.start + 6 * joint
                raw[moved, start : start + 6] = matrix_to_6d(torch.from_numpy(bent[moved, joint])).numpy()

    def _lift(self, side: int, places: np.ndarray, heights: np.ndarray) -> np.ndarray:
        """How far (N,) to raise one foot's ankle: its free joints (not held) lower than a contact height
        above where they land, moving along the ground faster than a planted foot does, go up to that
        height (a swinging foot clears the floor instead of sliding over it)."""
        index = slice(2 * side, 2 * side + 2)
        previous, floor = self.previous[:, index], self.floor[:, index]
        speed = np.linalg.norm(places - previous, axis=-1) * self.fps  # NaN on the first frame: no lift
        free = np.isnan(self.anchors[:, index, 0])
        gap = floor + self.height - heights
        skimming = free & (gap > 0) & (speed > self.speed)
        previous[:] = places
        lift = np.maximum(np.where(skimming, gap, 0.0).max(axis=1), LIFT_FADE * self.lifted[:, side])
        self.lifted[:, side] = lift
        return lift

    def _offset(self, side: int, places: np.ndarray, heights: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """The ankle offset (N, 2) of one foot this frame from its joints' (x, z) `places` (N, 2, 2),
        `heights` (N, 2) and contacts (N, 2), the state moved on."""
        anchors = self.anchors[:, 2 * side : 2 * side + 2]  # views: written through
        landed = self.landed[:, 2 * side : 2 * side + 2]
        last = self.offset[:, side]
        # A joint stays held after its contact ends until it rises a contact height above where it landed:
        # a foot still on the ground does not slide off its place while the walker lifts it.
        contact = contact | (~np.isnan(anchors[..., 0]) & (heights < landed + self.height))
        # A joint touching down is anchored where it lands (moved with its foot as the lock has it now).
        landing = contact & np.isnan(anchors[..., 0])
        anchors[landing] = (places + last[:, None])[landing]
        landed[landing] = heights[landing]
        floor = self.floor[:, 2 * side : 2 * side + 2]
        floor[landing] = np.where(np.isnan(floor), heights, 0.9 * floor + 0.1 * heights)[landing]
        anchors[~contact] = np.nan
        held = contact.any(axis=1)
        pulls = np.where(contact[..., None], anchors - places, 0.0)
        offset = pulls.sum(axis=1) / np.maximum(contact.sum(axis=1), 1)[:, None]
        # Held longer than the body's stride allows: the anchor is dragged along at the longest offset
        # (the foot slides rather than snapping back).
        length = np.linalg.norm(offset, axis=-1)
        dragged = length > self.max_offset
        offset[dragged] *= (self.max_offset / length[dragged])[:, None]
        anchors[dragged] = np.where(contact[dragged][..., None], (places + offset[:, None])[dragged], np.nan)
        # Lift-off: the last offset fades out; a foot put down again starts from no offset.
        lifted = ~held & (np.abs(last).sum(-1) > 0) & (self.fading[:, side] == 0)
        self.fading[lifted, side] = self.blend + 1
        fading = ~held & (self.fading[:, side] > 0)
        self.fading[fading, side] -= 1
        left = self.fading[:, side]  # frames of the fade still to come: the offset falls by 1 / (left + 1)
        offset[fading] = (last * (left / (left + 1))[:, None])[fading]
        self.fading[held, side] = 0
        self.offset[:, side] = offset
        return offset
