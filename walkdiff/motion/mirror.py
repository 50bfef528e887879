"""Mirror a clip left <-> right: the motion reflected in a plane, played by the same skeleton.

With M the reflection (M = diag(-1, 1, 1) for axis 'x'), every local rotation R becomes M R M and moves
to the joint's mirror partner, and the root's translation p becomes M p. The mirrored clip keeps its
skeleton's bone offsets, so its world positions are exactly the reflected, side-swapped world
positions of the original only when the skeleton itself is symmetric (M offset[left] == offset[right]).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from walkdiff.errors import WalkdiffError
from walkdiff.motion.skeleton import Motion, Skeleton

_AXES = {"x": 0, "y": 1, "z": 2}

# Name patterns of a left joint and how its right partner is spelled: 'Left'/'left'/'LEFT' anywhere,
# and a lone 'L' as a prefix before a capital or separator (LHipJoint, L_Hand) or a suffix after a
# separator (Hand_L, hand.l).
_SIDE_PATTERNS = [
    (re.compile(r"Left"), "Right"),
    (re.compile(r"left"), "right"),
    (re.compile(r"LEFT"), "RIGHT"),
    (re.compile(r"^L(?=[A-Z_.])"), "R"),
    (re.compile(r"(?<=[_.])L$"), "R"),
    (re.compile(r"(?<=[_.])l$"), "r"),
]


def find_mirror_pairs(skeleton: Skeleton) -> list[tuple[int, int]]:
    """(left, right) joint index pairs found by name."""
    pairs = []
    for left, name in enumerate(skeleton.names):
        for pattern, replacement in _SIDE_PATTERNS:
            candidate = pattern.sub(replacement, name, count=1)
            if candidate != name and candidate in skeleton.names:
                pairs.append((left, skeleton.index(candidate)))
                break
    return pairs


def _permutation(skeleton: Skeleton, pairs: Sequence[tuple[str, str]] | None) -> np.ndarray:
    """Index of each joint's mirror partner (itself for joints on the middle line)."""
    if pairs is None:
        index_pairs = find_mirror_pairs(skeleton)
    else:
        index_pairs = []
        for left, right in pairs:
            if left not in skeleton.names or right not in skeleton.names:
                raise WalkdiffError(f"mirror pair ({left!r}, {right!r}): expected two joints of the skeleton")
            index_pairs.append((skeleton.index(left), skeleton.index(right)))
    partner = np.arange(skeleton.num_joints)
    for left, right in index_pairs:
        if partner[left] != left or partner[right] != right or left == right:
            raise WalkdiffError(
                f"mirror pair ({skeleton.names[left]!r}, {skeleton.names[right]!r}): a joint is paired "
                "with itself or in more than one pair"
            )
        partner[left], partner[right] = right, left
    # The swap must map the hierarchy onto itself, or the mirrored clip would be on another skeleton.
    parents = skeleton.parents
    for joint in range(1, skeleton.num_joints):
        if partner[parents[joint]] != parents[partner[joint]]:
            raise WalkdiffError(
                f"mirror pairs do not match the hierarchy: {skeleton.names[joint]!r} and its partner "
                f"{skeleton.names[partner[joint]]!r} have parents that are not partners"
            )
    return partner


def mirror(motion: Motion, pairs: Sequence[tuple[str, str]] | None = None, axis: str = "x") -> Motion:
    """The clip reflected across the plane normal to `axis`, left and right joints swapped.

    `pairs` names (left, right) joints explicitly; by default they are found by name (see
    `find_mirror_pairs`). Joints without position channels keep their bone offsets.
    """
    if axis not in _AXES:
        raise WalkdiffError(f"mirror axis {axis!r}: expected one of {', '.join(_AXES)}")
    skeleton = motion.skeleton
    partner = _permutation(skeleton, pairs)
    sign = np.ones(3)
    sign[_AXES[axis]] = -1.0

    # M R M with M diagonal flips the signs of the entries that mix the reflected axis with the others.
    rotations = motion.rotations[:, partner] * (sign[:, None] * sign[None, :])
    positions = motion.positions[:, partner] * sign
    translated = np.array([bool(skeleton.position_order(j)) for j in range(skeleton.num_joints)])
    translated[0] = True  # the root always carries its world position
    positions[:, ~translated] = skeleton.offsets[~translated]
    return replace(motion, rotations=rotations, positions=positions)
