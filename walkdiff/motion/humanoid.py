"""The humanoid map: which joint of a skeleton plays which part of a human body.

Retargeting moves motion between skeletons that name, nest and pose their joints differently, so it
works on roles, not names:

- `pelvis`: the joint the legs and the spine hang from (the nearest common ancestor of the thighs);
- `spine`: the joints strictly between the pelvis and the neck (any number, none too);
- `neck` (optional: None when the spine runs straight into the head) and `head`;
- per side (`left_` / `right_`): `clavicle` (optional), `upper_arm`, `forearm`, `hand`; `thigh`, `shin`,
  `foot`, `toe` (optional);
- `fingers` (optional): per side and finger, the chain of joints from the hand's child to the tip,
  keyed `left_thumb`, `left_index`, `left_middle`, `left_ring`, `left_pinky` (and `right_...`).

Joints between two roles (CMU's `LHipJoint` between the pelvis and the thigh, a second neck joint, a
twist joint inside a limb chain) are *in between*: retargeting spreads the chain's motion over them
(or keeps them rigid with the pelvis or chest where the other rig has nothing there).
Every other joint (a static `Root` above the pelvis, twist and IK helpers beside the limbs, fingers a
rig has and the other has not) is unmapped and keeps its rest pose.

Roles are found in three steps: the overrides (configuration, a dict or YAML) win; then names, over
the conventions of CMU (`LeftUpLeg`, `LeftLeg`, `LThumb`), Mixamo (`mixamorig:LeftArm`), SMPL
(`left_hip`, `left_knee`, `left_collar`, `left_wrist`), Unreal (`thigh_l`, `calf_l`, `ball_l`,
`upperarm_l`, `lowerarm_l`, `spine_01`, `neck_01`), Unity humanoid (`LeftUpperLeg`, `LeftLowerArm`),
Blender (`thigh.L`), DAZ (`lThighBend`, `lShin`, `lShldrBend`) and 3ds Max Biped (`Bip01 L Thigh`,
`Bip01 L Calf`), with any side marking (`Left`/`Right`, `L`/`R` as a word, `_l`, `.L`, `L_`);
last the hierarchy itself (`walkdiff.motion.humanoid_geometry`) for limbs no name gives away.
A rig on which no legs or no arms are found is refused, naming the roles that are missing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.humanoid_geometry import find_limbs
from walkdiff.motion.posed_frames import ancestors, depth, rest_points, subtree, world_transforms
from walkdiff.motion.skeleton import Motion, Skeleton

SIDES = ("left", "right")
ARM_ROLES = ("clavicle", "upper_arm", "forearm", "hand")
LEG_ROLES = ("thigh", "shin", "foot", "toe")
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
OPTIONAL = ("neck", "clavicle", "toe")  # roles (or their side-less part) a rig may lack
SINGLE_ROLES = (
    "pelvis", "neck", "head",
    *(f"{side}_{part}" for side in SIDES for part in ARM_ROLES + LEG_ROLES),
)  # fmt: skip
FINGER_ROLES = tuple(f"{side}_{finger}" for side in SIDES for finger in FINGERS)


# ---------------------------------------------------------------- reading a joint name

_TOKEN = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
# Words that say nothing about the body part: exporters' prefixes (Bip01, DEF-, CC_Base_, jnt).
_NOISE = {"bip", "def", "cc", "base", "jnt", "bn", "mixamorig"}
# Words of helper bones: end markers, twist and roll bones, IK targets. Never a role themselves.
_HELPER = {
    "end", "nub", "site", "twist", "roll", "ik", "fk", "target", "pole", "helper", "corrective", "aux",
    "dummy", "null", "ctrl", "ctl", "goal", "tip", "top", "offset",
}  # fmt: skip
_SIDE_WORDS = {"l": "left", "left": "left", "r": "right", "right": "right"}

# Role words (lower case, side and noise removed, any trailing number). A strong word names the role
# alone; a weak one also names another role in some convention ('hip' is SMPL's thigh but a helper in
# Unreal-renamed CMU; 'shoulder' is the clavicle in CMU/Mixamo/Unity and the upper arm in SMPL; 'foot'
# is SMPL's toe), so it counts only where no strong word is found.
_STRONG = {
    "thigh": r"up(?:per)?leg|thigh(?:bend)?|uleg",
    "shin": r"leg|lo(?:wer)?leg|calf|knee|shin",
    "foot": r"foot|ankle",
    "toe": r"toes?|ball",
    "clavicle": r"clavicle|collar",
    "upper_arm": r"arm|up(?:per)?arm|shldr(?:bend)?",
    "forearm": r"forearm(?:bend)?|lo(?:wer)?arm|elbow",
    "hand": r"hand|wrist",
    "neck": r"neck(?:lower|upper|base)?",
    "head": r"head",
}
_WEAK = {"thigh": r"hip", "clavicle": r"shoulder", "upper_arm": r"shoulder", "toe": r"foot"}
_FINGER_WORDS = (
    ("thumb", "thumb"), ("index", "index"), ("middle", "middle"), ("ring", "ring"),
    ("pinky", "pinky"), ("pinky", "pinkie"), ("pinky", "little"),
)  # fmt: skip
_BIPED_FINGER = re.compile(r"finger(\d)")  # Biped: Finger0 is the thumb ... Finger4 the little finger


@dataclass(frozen=True)
class JointName:
    """A joint name read for its role: side, the remaining words run together, helper or not."""

    side: str | None
    key: str
    helper: bool


def read_name(name: str) -> JointName:
    """'mixamorig:LeftUpLeg' -> (left, 'upleg'); 'Bip01 L Calf' -> (left, 'calf'); 'thigh_twist_01_l'
    -> (left, 'thightwist01', helper)."""
    base = re.split(r"[:|]", name)[-1]
    tokens = [t for word in re.split(r"[^0-9A-Za-z]+", base) for t in _TOKEN.findall(word)]
    side, kept, helper, after_noise = None, [], False, False
    for token in tokens:
        low = token.lower()
        if low in _NOISE or (after_noise and token.isdigit()):
            after_noise = low in _NOISE
            continue
        after_noise = False
        if side is None and low in _SIDE_WORDS:
            side = _SIDE_WORDS[low]
            continue
        helper |= low in _HELPER
        kept.append(low)
    return JointName(side, "".join(kept), helper)


def _is(role: str, key: str, weak: bool = False) -> bool:
    words = (_WEAK if weak else _STRONG).get(role)
    return bool(words) and re.fullmatch(rf"(?:{words})\d*", key) is not None


def finger_of(key: str) -> str | None:
    """The finger a joint's key names ('handindex1' -> 'index'), or None."""
    biped = _BIPED_FINGER.search(key)
    if biped and int(biped.group(1)) < len(FINGERS):
        return FINGERS[int(biped.group(1))]
    return next((finger for finger, word in _FINGER_WORDS if word in key), None)


# ---------------------------------------------------------------- the map


@dataclass(frozen=True)
class HumanoidMap:
    """Joint names by role (see the module docstring); `found` says how each role was found (name,
    geometry, config), `notes` anything a user should know."""

    pelvis: str
    spine: tuple[str, ...]
    neck: str | None
    head: str
    left_clavicle: str | None
    left_upper_arm: str
    left_forearm: str
    left_hand: str
    right_clavicle: str | None
    right_upper_arm: str
    right_forearm: str
    right_hand: str
    left_thigh: str
    left_shin: str
    left_foot: str
    left_toe: str | None
    right_thigh: str
    right_shin: str
    right_foot: str
    right_toe: str | None
    fingers: dict[str, tuple[str, ...]] = field(default_factory=dict)
    found: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def joint(self, role: str) -> str | None:
        """The joint of a single role ('left_hand'), None for an optional role the rig lacks."""
        if role not in SINGLE_ROLES:
            raise WalkdiffError(
                f"humanoid map: unknown role {role!r}; expected one of {', '.join(SINGLE_ROLES)}"
            )
        return getattr(self, role)

    def roles(self) -> dict[str, str]:
        """Every single role the rig has -> its joint."""
        return {role: getattr(self, role) for role in SINGLE_ROLES if getattr(self, role) is not None}

    def mapped(self) -> set[str]:
        """Joints with a role: single roles, the spine and the fingers."""
        return set(self.roles().values()) | set(self.spine) | {j for c in self.fingers.values() for j in c}

    def in_between(self, skeleton: Skeleton) -> list[str]:
        """Joints on the chains between two roles without a role themselves (they follow their chain)."""
        mapped, out = self.mapped(), []
        for upper, lower in _role_links(self):
            for j in path_between(skeleton, skeleton.index(upper), skeleton.index(lower))[1:-1]:
                if skeleton.names[j] not in mapped and skeleton.names[j] not in out:
                    out.append(skeleton.names[j])
        return out

    def unmapped(self, skeleton: Skeleton) -> list[str]:
        """Joints neither mapped nor in between: retargeting leaves them in their rest pose."""
        used = self.mapped() | set(self.in_between(skeleton))
        return [n for n in skeleton.names if n not in used]

    def to_dict(self) -> dict:
        """The roles as a plain dict: the form overrides take."""
        out = {role: getattr(self, role) for role in SINGLE_ROLES}
        out["spine"] = list(self.spine)
        out.update({key: list(chain) for key, chain in self.fingers.items()})
        return out

    def describe(self, skeleton: Skeleton) -> list[str]:
        """Lines for `inspect`: each role, its joint and how it was found, then the joints left over."""
        lines = [f"{'pelvis':15s} {self.pelvis} [{self.found.get('pelvis', '')}]"]
        lines.append(f"{'spine':15s} {', '.join(self.spine) or '(none)'} [{self.found.get('spine', '')}]")
        for role in SINGLE_ROLES[1:]:
            joint = getattr(self, role)
            lines.append(f"{role:15s} {joint or '(none)'} [{self.found.get(role, 'not found')}]")
        for side in SIDES:
            chains = [
                f"{f} ({', '.join(self.fingers[f'{side}_{f}'])})"
                for f in FINGERS
                if f"{side}_{f}" in self.fingers
            ]
            lines.append(f"{side + ' fingers':15s} {'; '.join(chains) or '(none: left in rest pose)'}")
        between, unmapped = self.in_between(skeleton), self.unmapped(skeleton)
        lines.append(f"{'in between':15s} {', '.join(between) or '(none)'} (follow their chain)")
        lines.append(f"{'unmapped':15s} {', '.join(unmapped) or '(none)'} (kept in their rest pose)")
        return lines + [f"note: {n}" for n in self.notes]


def _role_links(m: HumanoidMap) -> list[tuple[str, str]]:
    """(upper, lower) joints of consecutive roles along every chain of the body."""
    central = [m.pelvis] + ([m.neck] if m.neck else []) + [m.head]
    links = list(zip(central, central[1:]))
    for side in SIDES:
        arm = [getattr(m, f"{side}_{p}") for p in ARM_ROLES]
        leg = [m.pelvis] + [getattr(m, f"{side}_{p}") for p in LEG_ROLES]
        for chain in (arm, leg):
            chain = [j for j in chain if j is not None]
            links += list(zip(chain, chain[1:]))
    return links


def path_between(skeleton: Skeleton, upper: int, lower: int) -> list[int]:
    """Joints from `upper` down to `lower` (a joint below it), both included."""
    chain = [lower]
    while chain[-1] != upper:
        parent = int(skeleton.parents[chain[-1]])
        if parent < 0:
            raise WalkdiffError(
                f"humanoid map: {skeleton.names[lower]!r} is not below {skeleton.names[upper]!r}"
            )
        chain.append(parent)
    return chain[::-1]


# ---------------------------------------------------------------- finding it


def humanoid_map(
    rig: Skeleton | Motion, overrides: dict | None = None, pose: np.ndarray | None = None
) -> HumanoidMap:
    """The humanoid map of a skeleton (or of a clip's skeleton).

    `overrides` maps roles to joint names (`spine` and finger roles to lists; None for an optional
    role the rig lacks) and wins over what is found. `pose`: world positions (J, 3) for the geometric
    fallback (default: a clip's first frame, a skeleton's rest pose). Raises a WalkdiffError naming the
    roles that are missing when no legs or arms are found, and naming the field for a bad override.
    """
    skeleton = rig.skeleton if isinstance(rig, Motion) else rig
    overrides = _checked_overrides(skeleton, overrides or {})
    names = [read_name(n) for n in skeleton.names]
    roles, found = _by_name(skeleton, names)
    for role, joint in overrides.items():
        if role in SINGLE_ROLES:
            roles[role], found[role] = joint, "config"
    notes: list[str] = []
    missing = [r for r in _required() if roles.get(r) is None]
    if missing:
        if pose is None:
            pose = (
                world_transforms(rig.slice(0, 1))[0][0] if isinstance(rig, Motion) else rest_points(skeleton)
            )
        for role, joint in _by_geometry(skeleton, names, pose[: skeleton.num_joints], roles, notes).items():
            if roles.get(role) is None and role not in overrides:
                roles[role], found[role] = joint, "geometry"
    missing = [r for r in _required() if roles.get(r) is None]
    if missing:
        raise WalkdiffError(_missing_message(skeleton, missing))
    index = {n: j for j, n in enumerate(skeleton.names)}
    if "pelvis" not in overrides:
        roles["pelvis"] = skeleton.names[
            _common_ancestor(skeleton, index[roles["left_thigh"]], index[roles["right_thigh"]])
        ]
        found["pelvis"] = "joint the thighs hang from"
    top = "neck" if roles.get("neck") else "head"
    spine = tuple(
        skeleton.names[j] for j in path_between(skeleton, index[roles["pelvis"]], index[roles[top]])[1:-1]
    )
    found["spine"] = f"joints between the pelvis and the {top}"
    if "spine" in overrides and tuple(overrides["spine"]) != spine:
        raise WalkdiffError(
            f"humanoid map: spine: expected the joints between the pelvis and the {top} "
            f"({', '.join(spine) or 'none'}), got {', '.join(overrides['spine']) or 'none'}"
        )
    fingers = {k: tuple(v) for k, v in overrides.items() if k in FINGER_ROLES and v}
    for side in SIDES:
        for key, chain in _finger_chains(skeleton, names, index[roles[f"{side}_hand"]], side).items():
            if key not in overrides:
                fingers[key] = tuple(skeleton.names[j] for j in chain)
    kept = {r: roles.get(r) for r in SINGLE_ROLES}
    result = HumanoidMap(
        spine=spine,
        fingers=fingers,
        found=found,
        notes=tuple(notes),
        **kept,  # type: ignore[arg-type]
    )
    _check_chains(skeleton, result)
    return result


def _by_geometry(skeleton, names, pose, roles, notes: list[str]) -> dict[str, str]:
    """Roles of the limbs (and head) the hierarchy shows, avoiding joints names gave other limbs."""
    index = {n: j for j, n in enumerate(skeleton.names)}
    avoid = {
        kind: {index[roles[f"{s}_{p}"]] for s in SIDES for p in parts if roles.get(f"{s}_{p}")}
        for kind, parts in (("legs", LEG_ROLES), ("arms", ARM_ROLES))
    }
    limbs = find_limbs(skeleton, names, pose, avoid)
    notes += limbs.notes
    out = {
        f"{side}_{part}": skeleton.names[j] for side, parts in limbs.legs.items() for part, j in parts.items()
    }
    out |= {
        f"{side}_{part}": skeleton.names[j] for side, parts in limbs.arms.items() for part, j in parts.items()
    }
    return out | {
        role: skeleton.names[j] for role, j in (("head", limbs.head), ("neck", limbs.neck)) if j is not None
    }


def _required() -> list[str]:
    optional = {"neck"} | {f"{s}_{p}" for s in SIDES for p in ("clavicle", "toe")}
    return [r for r in SINGLE_ROLES if r != "pelvis" and r not in optional]


def _missing_message(skeleton: Skeleton, missing: list[str]) -> str:
    parts = []
    for limb, parts_of in (("legs", LEG_ROLES), ("arms", ARM_ROLES)):
        gone = [r for r in missing if r.split("_", 1)[-1] in parts_of]
        if gone:
            parts.append(f"no {limb} ({', '.join(gone)})")
    if "head" in missing:
        parts.append("no head")
    shown = ", ".join(skeleton.names[:12]) + (" ..." if skeleton.num_joints > 12 else "")
    return (
        f"not a humanoid rig: {'; '.join(parts)} found by name or by the hierarchy among its joints "
        f"({shown}); name them in the humanoid map (e.g. left_thigh: <joint>)"
    )


def _checked_overrides(skeleton: Skeleton, overrides: dict) -> dict:
    known = set(SINGLE_ROLES) | {"spine"} | set(FINGER_ROLES)
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise WalkdiffError(
            f"humanoid map: unknown role(s) {', '.join(unknown)}; expected {', '.join(sorted(known))}"
        )
    out = {}
    for role, value in overrides.items():
        chained = role == "spine" or role in FINGER_ROLES
        values = list(value or []) if chained else [value]
        for name in values:
            if name is None and not chained and (role == "neck" or role.split("_", 1)[-1] in OPTIONAL):
                continue
            if not isinstance(name, str) or name not in skeleton.names:
                raise WalkdiffError(
                    f"humanoid map: {role}: expected {'joint names' if chained else 'a joint name'} of the "
                    f"skeleton, got {name!r}"
                )
        out[role] = values if chained else value
    return out


def _shallowest(skeleton: Skeleton, joints) -> int | None:
    joints = list(joints)
    return min(joints, key=lambda j: (depth(skeleton, j), j)) if joints else None


def _find(skeleton, names, role, side, below=None) -> int | None:
    """The shallowest joint of `side` (or of no side, below a joint) below `below` (anywhere when None)
    named by a strong word of `role`, else by a weak one."""
    pool = subtree(skeleton, below)[1:] if below is not None else range(skeleton.num_joints)
    pool = [
        j for j in pool
        if not names[j].helper and (names[j].side == side or (below is not None and names[j].side is None))
    ]  # fmt: skip
    for weak in (False, True):
        hit = _shallowest(skeleton, [j for j in pool if _is(role, names[j].key, weak)])
        if hit is not None:
            return hit
    return None


def _by_name(skeleton: Skeleton, names: list[JointName]) -> tuple[dict[str, str | None], dict[str, str]]:
    """Roles found by name (None where not found) and how."""
    idx: dict[str, int | None] = {}
    for side in SIDES:
        thigh = _find(skeleton, names, "thigh", side)
        shin = _find(skeleton, names, "shin", side, thigh) if thigh is not None else None
        foot = _find(skeleton, names, "foot", side, shin) if shin is not None else None
        toe = _find(skeleton, names, "toe", side, foot) if foot is not None else None
        upper = _upper_arm(skeleton, names, side)
        forearm = _find(skeleton, names, "forearm", side, upper) if upper is not None else None
        hand = _find(skeleton, names, "hand", side, forearm) if forearm is not None else None
        clavicle = _clavicle(skeleton, names, upper) if upper is not None else None
        if shin is None or foot is None:
            thigh = shin = foot = toe = None  # half a leg is no leg: geometry may find the whole
        if forearm is None or hand is None:
            upper = forearm = hand = clavicle = None
        idx |= {
            f"{side}_thigh": thigh, f"{side}_shin": shin, f"{side}_foot": foot, f"{side}_toe": toe,
            f"{side}_clavicle": clavicle, f"{side}_upper_arm": upper, f"{side}_forearm": forearm,
            f"{side}_hand": hand,
        }  # fmt: skip
    limbs = {j for j in idx.values() if j is not None}
    limbs |= {k for j in limbs for k in subtree(skeleton, j)}
    centre = [
        j
        for j in range(skeleton.num_joints)
        if names[j].side is None and not names[j].helper and j not in limbs
    ]
    idx["head"] = _shallowest(skeleton, [j for j in centre if _is("head", names[j].key)])
    necks = [j for j in centre if _is("neck", names[j].key)]
    if idx["head"] is not None:
        necks = [j for j in necks if j in ancestors(skeleton, idx["head"])]
    idx["neck"] = _shallowest(skeleton, necks)
    roles = {r: (None if j is None else skeleton.names[j]) for r, j in idx.items()}
    return roles, {r: "name" for r, j in idx.items() if j is not None}


def _upper_arm(skeleton, names, side) -> int | None:
    strong = [
        j
        for j in range(skeleton.num_joints)
        if names[j].side == side and not names[j].helper and _is("upper_arm", names[j].key)
    ]
    if strong:
        return _shallowest(skeleton, strong)
    # Only 'shoulder' words: below a collar it is the upper arm (SMPL); alone, the one with a forearm below.
    collar = _find(skeleton, names, "clavicle", side)
    if collar is not None and _is("clavicle", names[collar].key):
        return _find(skeleton, names, "upper_arm", side, collar)
    shoulders = [
        j
        for j in range(skeleton.num_joints)
        if names[j].side == side and _is("upper_arm", names[j].key, True)
    ]
    with_forearm = [j for j in shoulders if _find(skeleton, names, "forearm", side, j) is not None]
    return max(with_forearm, key=lambda j: depth(skeleton, j)) if with_forearm else None


def _clavicle(skeleton, names, upper: int) -> int | None:
    above = [j for j in ancestors(skeleton, upper) if not names[j].helper]
    for weak in (False, True):
        hits = [j for j in above if _is("clavicle", names[j].key, weak)]
        if hits:
            return hits[-1]  # the nearest above the upper arm
    return None


def _finger_chains(skeleton: Skeleton, names: list[JointName], hand: int, side: str) -> dict[str, list[int]]:
    """Per finger named below `hand`: the chain from the hand's child down to where it ends or forks."""
    chains: dict[str, list[int]] = {}
    for child in skeleton.children(hand):
        if names[child].helper:
            continue
        chain = [child]
        while True:
            below = [c for c in skeleton.children(chain[-1]) if not names[c].helper]
            if len(below) != 1:
                break
            chain.append(below[0])
        finger = next((finger_of(names[j].key) for j in chain if finger_of(names[j].key)), None)
        if finger is not None and f"{side}_{finger}" not in chains:
            chains[f"{side}_{finger}"] = chain
    return chains


def _common_ancestor(skeleton: Skeleton, a: int, b: int) -> int:
    above_a = set(ancestors(skeleton, a)) | {a}
    for j in [b, *ancestors(skeleton, b)[::-1]]:
        if j in above_a:
            return j
    raise WalkdiffError(f"humanoid map: {skeleton.names[a]!r} and {skeleton.names[b]!r} share no ancestor")


def _check_chains(skeleton: Skeleton, m: HumanoidMap) -> None:
    """Each role below the one before it on its chain, fingers chains below their hand, and no joint in
    two roles."""
    for upper, lower in _role_links(m):
        path_between(skeleton, skeleton.index(upper), skeleton.index(lower))
    for key, chain in m.fingers.items():
        hand = skeleton.index(m.joint(f"{key.split('_')[0]}_hand"))
        for upper, lower in zip([hand, *map(skeleton.index, chain)], map(skeleton.index, chain)):
            if upper not in ancestors(skeleton, lower) or (
                upper != hand and skeleton.parents[lower] != upper
            ):
                raise WalkdiffError(
                    f"humanoid map: {key}: expected a chain of joints below the hand, each the child of the "
                    f"one before; {skeleton.names[lower]!r} is not"
                )
    seen: dict[str, str] = {}
    for role, joint in [*m.roles().items(), *(("spine", j) for j in m.spine)]:
        if joint in seen and seen[joint] != role:
            raise WalkdiffError(f"humanoid map: joint {joint!r} is both {seen[joint]} and {role}")
        seen[joint] = role


def leg_length(skeleton: Skeleton, hmap: HumanoidMap) -> float:
    """Mean over both legs of the bone lengths from the thigh down to the foot, in the rig's units."""
    total = []
    for side in SIDES:
        joint, top = skeleton.index(hmap.joint(f"{side}_foot")), skeleton.index(hmap.joint(f"{side}_thigh"))
        length = 0.0
        while joint != top:
            length += float(np.linalg.norm(skeleton.offsets[joint]))
            joint = int(skeleton.parents[joint])
        total.append(length)
    if not np.mean(total) > 0:
        raise WalkdiffError("the legs have no length (thigh and foot at one place)")
    return float(np.mean(total))
