"""Mirror a clip left <-> right: the motion reflected in a plane, played by the same skeleton.

What it does. With M the reflection across the plane normal to `axis` (M = diag(-1, 1, 1) for 'x'; clips
are Y-up, so 'x' and 'z' are vertical planes) and partner[j] the joint on the other side of joint j
(itself on the centre line), the mirrored clip is built in world space:

- every joint j goes to the reflected position of its partner, P'[j] = M P[partner[j]];
- its world orientation becomes W'[j] = M W[partner[j]] M Q[j]. M W M is a proper rotation; Q[j] is a
  constant rest-pose correction that turns joint j's own rest frame into the mirror image of its
  partner's rest frame: the rotation that best maps j's child offsets (bone offsets of its children,
  End Site offsets) onto M times the partner's matching child offsets (Kabsch with two or more
  non-collinear children, the smallest rotation between the two vectors with one, identity for a leaf);
- local rotations follow as W'[parent]^T W'[j], which works out to the purely local
  Q[parent]^T (M L[partner[j]] M) Q[j]: no forward kinematics is needed for the rotations;
- the root's translation becomes M p; a non-root joint with position channels gets the local
  translation that puts it exactly at P'[j]; every other joint keeps its bone offset.

Why. Reflecting local rotations alone (M L M, swapped between partners) is exact only when the rest pose
is itself mirror-symmetric (M offset[left] == offset[right], i.e. mirror-symmetric local frames). Rigs
whose rest pose is not (an A-pose on one side, twisted local frames) come out far off: half the body
height on a test skeleton, where this method is exact. The correction Q makes the mirrored clip the
exact reflection on any skeleton whose two sides differ only by their rest frames. What no mirror that
keeps the skeleton's bone offsets can fix is a bone longer on one side than the other: the error left
is at most the sum, along the chain, of |Q[parent] offset[j] - M offset[partner[j]]| (zero when the
sides differ only by rest frames). Xia's right shin is 1.2% of body height longer than its left one,
ZEGGS's right forearm 1.8% shorter, so there mirrored clips stay up to 2% of body height off at the
extremities. With those bone lengths made equal this method is exact, the local mirror still 1.7% off
on Xia (0.5% on ZEGGS).

Mirroring twice is the identity (to float precision): Q is computed for one side and the centre line,
and the other side gets Q[partner] = M Q^T M, which makes the corrections of a pair cancel; for a
centre joint the Kabsch solution satisfies Q = M Q^T M by symmetry of its children. (Translated joints
need a partner with position channels too, which every rig seen so far has.)
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.skeleton import Motion, Skeleton

_AXES = {"x": 0, "y": 1, "z": 2}

# Separators between the words of a joint name: 'Bip01 L Foot', 'L_Ankle', 'Foot.L', 'mixamorig:Foot'.
_SEP = r"[\s_.:|\-]"
# Name patterns of a left joint and how its right partner is spelled. Tried in order; the first one
# whose right-hand spelling is a joint of the skeleton wins.
_SIDE_PATTERNS = [
    # 'Left'/'left'/'LEFT' anywhere: LeftFoot (CMU, Xia), mixamorig:LeftFoot, left_ankle (SMPL).
    (re.compile(r"Left"), "Right"),
    (re.compile(r"left"), "right"),
    (re.compile(r"LEFT"), "RIGHT"),
    # A lone capital L starting a word, before a capital or a separator: LHipJoint, LThumb (CMU),
    # L_Ankle (SMPL), 'Bip01 L Foot' (3ds Max Biped). Not LowerBack.
    (re.compile(rf"(?:^|(?<={_SEP}))L(?=[A-Z]|{_SEP})"), "R"),
    # A lone L or l ending the name after a separator: Foot_L, Foot.L, foot_l, thigh_l, hand.l.
    (re.compile(rf"(?<={_SEP})L$"), "R"),
    (re.compile(rf"(?<={_SEP})l$"), "r"),
    # A lone l starting the name before a separator: l_hip.
    (re.compile(rf"(?:^|(?<={_SEP}))l(?={_SEP})"), "r"),
    # DAZ Genesis: a lower-case l before a capital, lFoot, lThigh (not lowerJaw).
    (re.compile(r"(?:^|(?<=[:|]))l(?=[A-Z])"), "r"),
]


def find_mirror_pairs(skeleton: Skeleton) -> list[tuple[int, int]]:
    """(left, right) joint index pairs found by name (see `_SIDE_PATTERNS` for the conventions)."""
    return name_pairs(skeleton.names)


def name_pairs(names: Sequence[str]) -> list[tuple[int, int]]:
    """(left, right) index pairs of `names` whose partner is spelled there (see `_SIDE_PATTERNS`)."""
    pairs: list[tuple[int, int]] = []
    used: set[int] = set()
    index = {name: j for j, name in enumerate(names)}
    for left, name in enumerate(names):
        if left in used:
            continue
        for pattern, replacement in _SIDE_PATTERNS:
            candidate = pattern.sub(replacement, name, count=1)
            right = index.get(candidate)
            if candidate != name and right is not None and right not in used:
                pairs.append((left, right))
                used.update((left, right))
                break
    return pairs


def _no_pairs_error(skeleton: Skeleton) -> WalkdiffError:
    shown = ", ".join(skeleton.names[:8]) + (", ..." if skeleton.num_joints > 8 else "")
    return WalkdiffError(
        f"cannot mirror: no left/right joint pairs found by name among the joints ({shown}); "
        "name them with mirror pairs or turn mirroring off"
    )


def _check_hierarchy(skeleton: Skeleton, partner: np.ndarray) -> None:
    # The swap must map the hierarchy onto itself, or the mirrored clip would be on another skeleton.
    parents = skeleton.parents
    if partner[0] != 0:
        raise WalkdiffError(
            f"mirror pairs do not match the hierarchy: the root {skeleton.names[0]!r} is paired"
        )
    for joint in range(1, skeleton.num_joints):
        if partner[parents[joint]] != parents[partner[joint]]:
            raise WalkdiffError(
                f"mirror pairs do not match the hierarchy: {skeleton.names[joint]!r} and its partner "
                f"{skeleton.names[partner[joint]]!r} have parents that are not partners"
            )


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
    if not index_pairs:
        raise _no_pairs_error(skeleton)
    partner = np.arange(skeleton.num_joints)
    for left, right in index_pairs:
        if partner[left] != left or partner[right] != right or left == right:
            raise WalkdiffError(
                f"mirror pair ({skeleton.names[left]!r}, {skeleton.names[right]!r}): a joint is paired "
                "with itself or in more than one pair"
            )
        partner[left], partner[right] = right, left
    _check_hierarchy(skeleton, partner)
    return partner


def _checked_partner(skeleton: Skeleton, partner: np.ndarray) -> np.ndarray:
    """A caller's permutation, validated like the one built from pairs."""
    partner = np.asarray(partner)
    num_joints = skeleton.num_joints
    if partner.shape != (num_joints,) or not np.issubdtype(partner.dtype, np.integer):
        raise WalkdiffError(f"mirror partner: expected {num_joints} joint indices, got shape {partner.shape}")
    partner = partner.astype(np.int64)
    if partner.min() < 0 or partner.max() >= num_joints:
        raise WalkdiffError(f"mirror partner: indices must lie in 0..{num_joints - 1}")
    if not np.array_equal(partner[partner], np.arange(num_joints)):
        raise WalkdiffError("mirror partner: a joint is paired with itself or in more than one pair")
    if np.array_equal(partner, np.arange(num_joints)):
        raise _no_pairs_error(skeleton)
    _check_hierarchy(skeleton, partner)
    return partner


def _reflection(axis: str) -> np.ndarray:
    """Diagonal of M: the reflection across the plane normal to `axis`."""
    if axis not in _AXES:
        raise WalkdiffError(f"mirror axis {axis!r}: expected one of {', '.join(_AXES)}")
    sign = np.ones(3)
    sign[_AXES[axis]] = -1.0
    return sign


def _smallest_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation by the smallest angle that turns the direction of `a` into that of `b`."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    cross = np.cross(a, b)
    sin, cos = np.linalg.norm(cross), float(a @ b)
    if sin < 1e-12:
        if cos > 0:
            return np.eye(3)
        # Half turn about an axis normal to a. For a centre joint a lies along the mirror normal, so
        # this axis lies in the mirror plane and Q = M Q^T M still holds.
        helper = np.eye(3)[np.argmin(np.abs(a))]
        n = np.cross(a, helper)
        n /= np.linalg.norm(n)
        return 2.0 * np.outer(n, n) - np.eye(3)
    k = np.array([[0.0, -cross[2], cross[1]], [cross[2], 0.0, -cross[0]], [-cross[1], cross[0], 0.0]])
    return np.eye(3) + k + k @ k * ((1.0 - cos) / sin**2)


def _best_rotation(source: np.ndarray, target: np.ndarray, tiny: float) -> np.ndarray:
    """The rotation Q that best maps each row of `source` onto the same row of `target`."""
    keep = (np.linalg.norm(source, axis=1) > tiny) & (np.linalg.norm(target, axis=1) > tiny)
    source, target = source[keep], target[keep]
    if len(source) == 0:
        return np.eye(3)
    spread = np.linalg.svd(source, compute_uv=False)
    if len(source) >= 2 and spread[1] > 1e-6 * spread[0]:
        # Kabsch: maximise trace(Q^T H), H = sum target source^T, over proper rotations.
        u, _, vt = np.linalg.svd(target.T @ source)
        d = np.sign(np.linalg.det(u @ vt))
        return u @ np.diag([1.0, 1.0, d]) @ vt
    longest = np.argmax(np.linalg.norm(source, axis=1))
    return _smallest_rotation(source[longest], target[longest])


def rest_corrections(skeleton: Skeleton, partner: np.ndarray, axis: str = "x") -> np.ndarray:
    """(J, 3, 3) rest-pose corrections Q: Q[j] maps joint j's child offsets onto M times its partner's.

    `partner` is a checked permutation (each joint's partner, the hierarchy mapped onto itself). Q is
    computed for the centre line and for the joint of each pair that comes first; the other one gets
    M Q^T M, so that mirroring twice gives back the original rotations.
    """
    sign = _reflection(axis)
    flip = np.outer(sign, sign)  # M X M == X * flip for a diagonal M
    partner = np.asarray(partner)
    offsets, parents = skeleton.offsets, skeleton.parents
    children: list[list[int]] = [[] for _ in range(skeleton.num_joints)]
    for joint in range(1, skeleton.num_joints):
        children[parents[joint]].append(joint)
    scale = max(float(np.abs(offsets).max(initial=0.0)), 1e-300)
    corrections = np.tile(np.eye(3), (skeleton.num_joints, 1, 1))
    for joint in range(skeleton.num_joints):
        other = int(partner[joint])
        if other < joint:
            continue  # set with its partner
        source = [offsets[c] for c in children[joint]]
        target = [offsets[partner[c]] * sign for c in children[joint]]
        if joint in skeleton.end_sites and other in skeleton.end_sites:
            source.append(np.asarray(skeleton.end_sites[joint], dtype=np.float64))
            target.append(np.asarray(skeleton.end_sites[other], dtype=np.float64) * sign)
        if source:
            corrections[joint] = _best_rotation(np.array(source), np.array(target), 1e-9 * scale)
        if other != joint:
            corrections[other] = corrections[joint].T * flip
    return corrections


def mirror(
    motion: Motion,
    pairs: Sequence[tuple[str, str]] | None = None,
    axis: str = "x",
    *,
    partner: np.ndarray | None = None,
) -> Motion:
    """The clip reflected across the plane normal to `axis`, left and right joints swapped.

    `pairs` names (left, right) joints explicitly; by default they are found by name (see
    `find_mirror_pairs`). `partner` instead gives each joint's partner index directly (itself on the
    centre line). A skeleton without any left/right pair raises a WalkdiffError. See the module
    docstring for the construction.
    """
    sign = _reflection(axis)
    skeleton = motion.skeleton
    if partner is None:
        partner = _permutation(skeleton, pairs)
    elif pairs is not None:
        raise WalkdiffError("mirror: give either pairs or partner, not both")
    else:
        partner = _checked_partner(skeleton, partner)
    flip = np.outer(sign, sign)
    corrections = rest_corrections(skeleton, partner, axis)
    parents = skeleton.parents

    # L'[j] = W'[parent]^T W'[j] with W'[j] = M W[partner[j]] M Q[j], and since partner[parent[j]] is the
    # parent of partner[j]: L'[j] = Q[parent]^T (M L[partner[j]] M) Q[j] (the root has no Q[parent]).
    parent_corrections = corrections[parents]
    parent_corrections[0] = np.eye(3)
    rotations = np.matmul(
        np.matmul(parent_corrections.transpose(0, 2, 1), motion.rotations[:, partner] * flip), corrections
    )

    translated = np.array([bool(skeleton.position_order(j)) for j in range(skeleton.num_joints)])
    translated[0] = True  # the root always carries its world position
    positions = np.empty_like(motion.positions)
    positions[:] = skeleton.offsets
    positions[:, 0] = motion.positions[:, 0] * sign
    if translated[1:].any():
        positions = _solve_translations(motion, rotations, positions, partner, sign, translated)
    return replace(motion, rotations=rotations, positions=positions)


def _solve_translations(
    motion: Motion,
    rotations: np.ndarray,
    positions: np.ndarray,
    partner: np.ndarray,
    sign: np.ndarray,
    translated: np.ndarray,
) -> np.ndarray:
    """Local translations that put every translated joint at M P[partner] (forward kinematics, in order)."""
    target = motion_world_positions(motion)[:, partner] * sign
    parents = motion.skeleton.parents
    last = int(np.flatnonzero(translated).max())
    world_rot = [rotations[:, 0]]
    world_pos = [positions[:, 0]]
    for joint in range(1, last + 1):
        parent = parents[joint]
        if translated[joint]:
            positions[:, joint] = np.einsum(
                "fij,fi->fj", world_rot[parent], target[:, joint] - world_pos[parent]
            )
            world_pos.append(target[:, joint])
        else:
            world_pos.append(
                world_pos[parent] + np.einsum("fij,fj->fi", world_rot[parent], positions[:, joint])
            )
        world_rot.append(np.matmul(world_rot[parent], rotations[:, joint]))
    return positions
