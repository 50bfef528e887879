"""Limbs from the shape of the hierarchy: the humanoid map's fallback for joints no name gives away.

Limbs are pairs of children of one joint whose subtrees have the same shape (joint count and depth) and
chain lengths within SYMMETRY of each other, at least LIMB_SHARE of the body long. The legs are the pair
that branches nearest the root (at the pelvis) among those whose chains end on the floor where most
joints touch it (`floor_contacts`: never eye stalks or claws), the arms the nearest pair below it outside
the legs (at the spine's top), the head the end of the longest other chain from where the arms branch.
Along a leg the thigh and shin are the two longest consecutive bones; along an arm the hand is the first
joint where the chain forks into something shorter than the bone into it (fingers), else its end, with
the forearm, upper arm and clavicle above it. Sides come from names where any joint of a chain has one,
else from the pose: left is up x forward, forward the way the toes point (the file's +z when there are
none, said in the notes).

Joints are read through objects with `side` and `helper` (`walkdiff.motion.humanoid.JointName`): helper
bones (twist, IK, end markers) are never part of a limb's main chain.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from walkdiff.motion.posed_frames import depth, floor_contacts, subtree
from walkdiff.motion.skeleton import Skeleton

LIMB_SHARE = 0.25  # a limb chain is at least this share of the longest bone path from the root
SYMMETRY = 0.15  # two chains pair up when their lengths differ by less than this share


@dataclass
class Limbs:
    """Joint indices found: per side, the leg's thigh/shin/foot(/toe) and the arm's (clavicle/)
    upper_arm/forearm/hand; the head and neck (None when not found); notes on how."""

    legs: dict[str, dict[str, int]] = field(default_factory=dict)
    arms: dict[str, dict[str, int]] = field(default_factory=dict)
    head: int | None = None
    neck: int | None = None
    notes: list[str] = field(default_factory=list)


def find_limbs(skeleton: Skeleton, names, pose: np.ndarray, avoid: dict[str, set[int]]) -> Limbs:
    """Legs, arms, head and neck from the hierarchy (see the module docstring). `pose`: world positions
    (J, 3); `avoid`: joints names already gave the arms ('arms') and the legs ('legs'), which the other
    limb's pair may not contain."""
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    reach = _reach(skeleton, names, lengths)
    scale = max(float(reach[0]), 1e-12)
    pairs = _symmetric_pairs(skeleton, names, lengths, reach)
    pairs = [p for p in pairs if lengths[p[1]] + reach[p[1]] >= LIMB_SHARE * scale]
    out = Limbs()
    # Legs end on the floor, where the most joints touch it: never eye stalks or claws held out.
    ends = {j: _main_chain(skeleton, names, lengths, reach, j)[-1] for pair in pairs for j in pair[1:]}
    contacts = {p: floor_contacts(pose, p[0], [ends[p[1]], ends[p[2]]]) for p in pairs}
    most = max(contacts.values(), default=0)
    standing = [p for p in pairs if contacts[p] == most > 0]
    legs = _pick(skeleton, standing, avoid.get("arms", set()), inside=None, outside=[])
    if legs is None:
        return out
    branch, a, b = legs
    chains = [_main_chain(skeleton, names, lengths, reach, c) for c in (a, b)]
    found = [_leg_roles(chain, lengths) for chain in chains]
    up, forward, how = _body_axes(pose, branch, found)
    sides, by_pose = _sides(names, pose, branch, chains, up, forward)
    if all(found):
        out.legs = dict(zip(sides, found))
        out.notes.append(f"legs found from the hierarchy; sides from {how if by_pose else 'names'}")
    arms = _pick(skeleton, pairs, avoid.get("legs", set()), inside=branch, outside=[a, b])
    if arms is None:
        return out
    arm_branch, c, d = arms
    chains = [_main_chain(skeleton, names, lengths, reach, x) for x in (c, d)]
    found = [_arm_roles(skeleton, names, chain, lengths, reach) for chain in chains]
    sides, by_pose = _sides(names, pose, arm_branch, chains, up, forward)
    if all(found):
        out.arms = dict(zip(sides, found))
        out.notes.append(f"arms found from the hierarchy; sides from {how if by_pose else 'names'}")
    out.head, out.neck = _head(skeleton, names, lengths, reach, arm_branch, (c, d))
    return out


def _kids(skeleton: Skeleton, names, joint: int) -> list[int]:
    return [c for c in skeleton.children(joint) if not names[c].helper]


def _reach(skeleton: Skeleton, names, lengths: np.ndarray) -> np.ndarray:
    """Per joint, the longest bone path from it down to a leaf (helpers left out)."""
    reach = np.zeros(skeleton.num_joints)
    for j in range(skeleton.num_joints - 1, 0, -1):  # children come after parents: bottom up
        if not names[j].helper:
            p = int(skeleton.parents[j])
            reach[p] = max(reach[p], lengths[j] + reach[j])
    return reach


def _symmetric_pairs(skeleton: Skeleton, names, lengths, reach) -> list[tuple[int, int, int]]:
    """(branch, child, child) for every two children of one joint with same-shaped subtrees."""

    def shape(j: int) -> tuple[int, int]:
        inside = subtree(skeleton, j)
        return len(inside), max(depth(skeleton, k) for k in inside) - depth(skeleton, j)

    out = []
    for branch in range(skeleton.num_joints):
        kids = _kids(skeleton, names, branch)
        for i, a in enumerate(kids):
            for b in kids[i + 1 :]:
                la, lb = lengths[a] + reach[a], lengths[b] + reach[b]
                if shape(a) == shape(b) and abs(la - lb) <= SYMMETRY * max(la, lb):
                    out.append((branch, a, b))
    return out


def _pick(skeleton: Skeleton, pairs, avoid: set[int], inside: int | None, outside: list[int]):
    """The pair branching nearest the root below `inside` (anywhere when None), outside the subtrees of
    `outside`, with no joint of `avoid` in its chains."""

    def ok(pair) -> bool:
        branch, a, b = pair
        if (set(subtree(skeleton, a)) | set(subtree(skeleton, b))) & avoid:
            return False
        if any(branch in subtree(skeleton, o) or o in (a, b) for o in outside):
            return False
        return inside is None or branch in subtree(skeleton, inside)

    good = [p for p in pairs if ok(p)]
    return min(good, key=lambda p: (depth(skeleton, p[0]), p[0])) if good else None


def _main_chain(skeleton: Skeleton, names, lengths, reach, joint: int) -> list[int]:
    """`joint` and, down from it, each time the child with the longest path below."""
    chain = [joint]
    while kids := _kids(skeleton, names, chain[-1]):
        chain.append(max(kids, key=lambda c: lengths[c] + reach[c]))
    return chain


def _leg_roles(chain: list[int], lengths: np.ndarray) -> dict[str, int]:
    if len(chain) < 3:
        return {}
    i = max(range(len(chain) - 2), key=lambda k: lengths[chain[k + 1]] + lengths[chain[k + 2]])
    found = {"thigh": chain[i], "shin": chain[i + 1], "foot": chain[i + 2]}
    return found | ({"toe": chain[i + 3]} if i + 3 < len(chain) else {})


def _arm_roles(skeleton: Skeleton, names, chain: list[int], lengths, reach) -> dict[str, int]:
    """Hand, forearm, upper arm and clavicle along an arm chain: the hand is the first joint that forks
    into what is shorter than the bone into it (fingers, not a forearm beside a stub), else the end."""
    forks = [
        k for k in range(2, len(chain))
        if len(_kids(skeleton, names, chain[k])) >= 2 and reach[chain[k]] < lengths[chain[k]]
    ]  # fmt: skip
    k = forks[0] if forks else len(chain) - 1
    if k < 2:
        return {}
    found = {"hand": chain[k], "forearm": chain[k - 1], "upper_arm": chain[k - 2]}
    return found | ({"clavicle": chain[k - 3]} if k >= 3 else {})


def _body_axes(pose: np.ndarray, pelvis: int, legs: list[dict[str, int]]):
    """Up (feet to pelvis), forward (where the toes point, else the file's +z across up), and how."""
    feet = [leg["foot"] for leg in legs if "foot" in leg]
    up = pose[pelvis] - pose[feet].mean(axis=0) if feet else np.array([0.0, 1.0, 0.0])
    up = up / max(np.linalg.norm(up), 1e-12)
    toes = [pose[leg["toe"]] - pose[leg["foot"]] for leg in legs if "toe" in leg]
    forward = np.mean(toes, axis=0) if toes else np.zeros(3)
    forward = forward - (forward @ up) * up
    how = "the pose (left = up x the toes' direction)"
    if np.linalg.norm(forward) < 1e-9 * max(float(np.abs(pose).max()), 1e-12):
        forward = np.array([0.0, 0.0, 1.0]) - up[2] * up
        how = "the pose, assuming the rig faces the file's +z (it has no toes): check the sides"
    return up, forward / max(np.linalg.norm(forward), 1e-12), how


def _sides(names, pose, branch: int, chains, up, forward) -> tuple[tuple[str, str], bool]:
    """('left', 'right') or ('right', 'left') for two chains, and whether the pose (not names) told."""
    votes = []
    for chain in chains:
        sides = [names[j].side for j in chain if names[j].side]
        votes.append(max(set(sides), key=sides.count) if sides else None)
    if votes[0] and votes[1] and votes[0] != votes[1]:
        return (votes[0], votes[1]), False
    left = np.cross(up, forward)
    first, second = ((pose[chain].mean(axis=0) - pose[branch]) @ left for chain in chains)
    return (("left", "right") if first >= second else ("right", "left")), True


def _head(skeleton: Skeleton, names, lengths, reach, branch: int, arms) -> tuple[int | None, int | None]:
    """Head (end of the longest chain from the arms' branch that is not an arm) and neck (the chain's
    first joint when it has more than one)."""
    others = [c for c in _kids(skeleton, names, branch) if c not in arms]
    if not others:
        return None, None
    chain = _main_chain(skeleton, names, lengths, reach, max(others, key=lambda c: lengths[c] + reach[c]))
    return chain[-1], (chain[0] if len(chain) > 1 else None)
