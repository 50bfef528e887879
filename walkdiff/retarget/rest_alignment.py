"""How two rigs' joints stand against each other in their reference poses: retargeting's constants.

Retargeting gives every driven target joint j the world rotation

    R_t(f, j) = S(f, j) R_s(f, s) C(j),    C(j) = W_s(s)^T D(j) W_t(j),

where s is the source joint that drives j, W the world rotations of both rigs in their reference poses
(rest poses, or posed frames where a rest pose is no pose), all in canonical axes (Y up), and D(j) the
world rotation that lays the target's reference bone frame onto the source's: its bone direction onto
the source's bone direction and a second direction onto the source's (for the twist about the bone).
So a joint turns in the world as its driver turns away from its own reference pose: a T-pose source
drives an A-pose target, local frames turned any way, and the full rotation (twist included) is carried,
which keeps hands and feet facing where the source's face. S(f, j) is a swing for chains the two rigs
divide differently: it turns the bone onto the source's chord over the same share of the chain's
length (`Drive.chord`), so a spine of 3 joints drives one of 5 without bending it elsewhere. The pelvis
has one too when the source's hips move against it (CMU's hip joints) and the target's do not: its
chord is the source's live hip line, which the target's thighs then sit on.

Correspondence (`_links`): the chains of the humanoid map (pelvis-neck-head-head's end, pelvis-thigh-
shin-foot-toe-toe's end, spine-clavicle-upper arm-forearm-hand-hand's end, hand-finger-finger's end),
cut at the roles both rigs have. A target joint on a chain covers a share [b, c] of its length; its
driver is the source joint of the chain covering most of that share. A joint between a hub (the pelvis,
the chest, a hand) and the next role that the source has nothing for (CMU's hip joint against a rig
whose thighs hang from the pelvis) is not driven: it stays rigid with the hub, as the source's is.

Reference bone frames (`_lay`): a joint's bone direction is its own segment when both rigs have it
non-zero, else the whole chain's, else the previous chain's. Its twist about the bone comes from a
second direction where the joint has one of its own: the left-right line of what hangs from it (the
hips from the pelvis, the arms from the chest, the fingers from the hand), which makes world positions
exact between rigs that differ only in rest pose and local frames (every child offset lands where the
source's does). Any other joint takes its parent's D, swung so that the bone directions meet: the
twist relative to the parent bone is taken to be the source's, so a limb re-posed at rest as a whole
(arms from T to A, legs spread) keeps its hands' and feet's facing. Above every driven joint (a static
root) D turns the target's body axes (forward, up, left) onto the source's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from walkdiff.motion.humanoid import FINGERS, SIDES, HumanoidMap, path_between
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.posed_frames import subtree
from walkdiff.motion.rotations import rotation_between
from walkdiff.motion.skeleton import Motion, Skeleton

Point = tuple[int, "np.ndarray | None"]  # a joint, and an offset in its own frame (an End Site) or None
TINY = 1e-6  # of the body's size: shorter is no direction
HAND_FINGERS = ("middle", "index", "ring", "pinky")  # the hand's own direction: the first both rigs have
FINGER_PAIRS = (
    ("index", "pinky"),
    ("index", "ring"),
    ("middle", "pinky"),
    ("index", "middle"),
    ("middle", "ring"),
)


@dataclass
class Reference:
    """One rig in its reference pose: world positions (J, 3) and rotations (J, 3, 3) in canonical axes
    (`turn` takes file axes there), the local transforms of the pose (file axes), and how it was chosen."""

    skeleton: Skeleton
    hmap: HumanoidMap
    turn: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    local_rotations: np.ndarray
    local_positions: np.ndarray
    how: str

    def index(self, role: str) -> int | None:
        name = self.hmap.joint(role)
        return None if name is None else self.skeleton.index(name)

    def at(self, point: Point) -> np.ndarray:
        joint, offset = point
        return (
            self.positions[joint]
            if offset is None
            else self.positions[joint] + self.rotations[joint] @ offset
        )

    @property
    def size(self) -> float:
        return max(float(np.ptp(self.positions, axis=0).max()), 1e-12)

    def body_axes(self) -> dict[str, np.ndarray]:
        """The rig's forward, up and left in this pose: left across the thighs (on the floor), up +Y."""
        up = np.array([0.0, 1.0, 0.0])
        for pair in (("left_thigh", "right_thigh"), ("left_upper_arm", "right_upper_arm")):
            left = self.positions[self.index(pair[0])] - self.positions[self.index(pair[1])]
            left = left - (left @ up) * up
            if np.linalg.norm(left) > TINY * self.size:
                break
        else:
            left = np.array([1.0, 0.0, 0.0])
        left /= np.linalg.norm(left)
        return {"forward": np.cross(left, up), "up": up, "left": left}


def reference_pose(
    motion: Motion, frame: int | None, turn: np.ndarray, hmap: HumanoidMap, how: str
) -> Reference:
    """The pose of `motion`'s skeleton at `frame` (None: its rest pose, every rotation the identity)."""
    skeleton = motion.skeleton
    if frame is None:
        local_rot = np.broadcast_to(np.eye(3), (skeleton.num_joints, 3, 3)).copy()
        local_pos = skeleton.offsets.copy()
    else:
        local_rot, local_pos = motion.rotations[frame].copy(), motion.positions[frame].copy()
    pos, rot = forward_kinematics(local_rot, local_pos, skeleton.parents, return_rotations=True)
    return Reference(skeleton, hmap, turn, pos @ turn.T, turn @ rot, local_rot, local_pos, how)


def pose_points(ref: Reference) -> np.ndarray:
    """Joints then End Sites of the reference pose (for `posed_frames.rest_pose_problem`)."""
    ends = [ref.at((j, np.asarray(o))) for j, o in ref.skeleton.end_sites.items()]
    return np.concatenate([ref.positions, np.reshape(ends, (-1, 3))])


# ---------------------------------------------------------------- chains both rigs share


@dataclass
class Chain:
    """One chain of the body in one rig: its points from start to end, and the share of the chain's
    length at each point (0 at the start, 1 at the end; all 0 for a chain of no length)."""

    points: list[Point]
    fractions: np.ndarray

    @classmethod
    def of(cls, ref: Reference, points: list[Point]) -> Chain:
        places = np.array([ref.at(p) for p in points])
        steps = np.linalg.norm(np.diff(places, axis=0), axis=1) if len(points) > 1 else np.zeros(0)
        total = steps.sum()
        cumulative = np.concatenate([[0.0], np.cumsum(steps)])
        return cls(points, cumulative / total if total > TINY * ref.size else np.zeros(len(points)))

    def locate(self, share: float) -> tuple[int, float]:
        """(k, t): the place at `share` of the chain lies a share t of the way from point k to k + 1."""
        k = int(np.clip(np.searchsorted(self.fractions, share, side="right") - 1, 0, len(self.points) - 2))
        span = self.fractions[k + 1] - self.fractions[k]
        return k, float(np.clip((share - self.fractions[k]) / span, 0.0, 1.0)) if span > 0 else 0.0

    def place(self, ref: Reference, share: float) -> np.ndarray:
        k, t = self.locate(share)
        return (1 - t) * ref.at(self.points[k]) + t * ref.at(self.points[k + 1])


@dataclass
class Link:
    """A chain in both rigs. `owns_start`: its first joint is driven along it (not a hub: the pelvis,
    the joint the arms hang from, a hand with fingers); `previous`: the link ending where it starts."""

    name: str
    source: Chain
    target: Chain
    owns_start: bool
    previous: int | None


def _central(ref: Reference) -> list[int]:
    """The joints from the pelvis to the head."""
    return path_between(ref.skeleton, ref.index("pelvis"), ref.index("head"))


def _attach(ref: Reference, side: str) -> int:
    """The joint of the central chain an arm hangs from."""
    central = set(_central(ref))
    top = ref.index(f"{side}_clavicle") or ref.index(f"{side}_upper_arm")
    joint = int(ref.skeleton.parents[top])
    while joint not in central and joint >= 0:
        joint = int(ref.skeleton.parents[joint])
    return joint


def _finger(ref: Reference, key: str) -> list[int]:
    return [ref.skeleton.index(n) for n in ref.hmap.fingers.get(key, ())]


def _first_away(ref: Reference, points: list[Point]) -> np.ndarray | None:
    """The first of `points` at a distance from the first one, less the first: a direction rigid with
    the start joint where the rig has one (its own child), else the nearest there is."""
    point = _first_point_away(ref, points)
    return None if point is None else ref.at(point) - ref.at(points[0])


def _first_point_away(ref: Reference, points: list[Point]) -> Point | None:
    start = ref.at(points[0])
    return next((p for p in points[1:] if np.linalg.norm(ref.at(p) - start) > TINY * ref.size), None)


def _end(ref: Reference, joint: int, side: str | None = None) -> Point | None:
    """Where a chain's last joint points: a hand (`side` given) to its first finger's base, else the
    joint's End Site, else its farthest descendant; None when all of it is at the joint."""
    tiny = TINY * ref.size
    skeleton = ref.skeleton
    below = subtree(skeleton, joint)[1:]
    if side is not None:
        for finger in HAND_FINGERS:
            for j in _finger(ref, f"{side}_{finger}"):
                if np.linalg.norm(ref.positions[j] - ref.positions[joint]) > tiny:
                    return j, None
    site = skeleton.end_sites.get(joint)
    if site is not None and np.linalg.norm(site) > tiny:
        return joint, np.asarray(site, dtype=np.float64)
    points: list[Point] = [(j, None) for j in below]
    points += [
        (j, np.asarray(skeleton.end_sites[j], dtype=np.float64)) for j in below if j in skeleton.end_sites
    ]
    far = max(points, key=lambda p: np.linalg.norm(ref.at(p) - ref.positions[joint]), default=None)
    return far if far is not None and np.linalg.norm(ref.at(far) - ref.positions[joint]) > tiny else None


def _common_fingers(src: Reference, tgt: Reference, side: str) -> list[str]:
    return [f for f in FINGERS if f"{side}_{f}" in src.hmap.fingers and f"{side}_{f}" in tgt.hmap.fingers]


def _hand_is_hub(src: Reference, tgt: Reference, side: str) -> bool:
    """A hand both rigs give fingers (other than the thumb) is framed by them, not by its end."""
    return any(f != "thumb" for f in _common_fingers(src, tgt, side))


def _stops(src: Reference, tgt: Reference) -> list[tuple[str, list[str]]]:
    """Per chain, the roles it runs through that both rigs have; 'end:R' is R's end, 'attach:S' the
    joint side S's arm hangs from, 'finger:K' finger K's joints then their end."""

    def both(role: str) -> bool:
        return src.index(role) is not None and tgt.index(role) is not None

    chains = [("central", ["pelvis"] + (["neck"] if both("neck") else []) + ["head", "end:head"])]
    for side in SIDES:
        toe = both(f"{side}_toe")
        leg = ["pelvis", f"{side}_thigh", f"{side}_shin", f"{side}_foot"]
        chains.append(
            (f"{side} leg", leg + ([f"{side}_toe", f"end:{side}_toe"] if toe else [f"end:{side}_foot"]))
        )
        arm = [f"attach:{side}"] + ([f"{side}_clavicle"] if both(f"{side}_clavicle") else [])
        arm += [f"{side}_upper_arm", f"{side}_forearm", f"{side}_hand"]
        chains.append((f"{side} arm", arm + ([] if _hand_is_hub(src, tgt, side) else [f"end:{side}_hand"])))
        for finger in _common_fingers(src, tgt, side):
            chains.append((f"{side} {finger}", [f"{side}_hand", f"finger:{side}_{finger}"]))
    return chains


def _joint_of(ref: Reference, stop: str) -> int:
    if stop.startswith("attach:"):
        return _attach(ref, stop.split(":")[1])
    return ref.index(stop)


def _points(ref: Reference, start: str, stop: str, with_end: bool) -> list[Point]:
    """A link's points in one rig: the hierarchy path between two roles, a role and its end, or a hand
    and one finger's joints and their end. Without an end (`with_end` False, or none found) a chain
    ends in a point of no length at its last joint, so that joint is still driven along it."""
    first = _joint_of(ref, start)
    if stop.startswith(("end:", "finger:")):
        chain = [first] if stop.startswith("end:") else [first] + _finger(ref, stop.split(":")[1])
        side = start.split("_")[0] if start.endswith("_hand") and stop.startswith("end:") else None
        end = _end(ref, chain[-1], side) if with_end else None
        return [(j, None) for j in chain] + [end if end is not None else (chain[-1], np.zeros(3))]
    return [(j, None) for j in path_between(ref.skeleton, first, _joint_of(ref, stop))]


def _has_end(ref: Reference, start: str, stop: str) -> bool:
    if not stop.startswith(("end:", "finger:")):
        return True
    last = _points(ref, start, stop, True)[-1]
    return last[1] is None or bool(np.any(last[1]))


def _links(src: Reference, tgt: Reference) -> list[Link]:
    hubs = {"pelvis", "attach:left", "attach:right"}
    hubs |= {f"{side}_hand" for side in SIDES if _hand_is_hub(src, tgt, side)}
    links: list[Link] = []
    for name, stops in _stops(src, tgt):
        previous = None
        for start, stop in zip(stops, stops[1:]):
            # An end only one rig has is no common direction: both chains stop at the joint then.
            with_end = _has_end(src, start, stop) and _has_end(tgt, start, stop)
            chains = [Chain.of(r, _points(r, start, stop, with_end)) for r in (src, tgt)]
            links.append(Link(f"{name}: {start} - {stop}", *chains, start not in hubs, previous))
            previous = len(links) - 1
    return links


# ---------------------------------------------------------------- per joint


@dataclass
class Drive:
    """Target joint `target` follows source joint `source`: R_t = S R_s[source] @ `constant`. `chord`
    (source chain, share from, share to, the chord in the source joint's frame) when S is needed."""

    target: int
    source: int
    constant: np.ndarray
    chord: tuple[Chain, float, float, np.ndarray] | None = None


@dataclass
class _Spec:
    """What lays a driven target joint onto its source joint, before its D is known: its bone direction
    in both rigs (source, target), second directions where the joint has its own (source, target), and
    the source chord it follows where the rigs divide its chain differently."""

    target: int
    source: int
    primary: tuple[np.ndarray, np.ndarray] | None
    secondary: tuple[np.ndarray, np.ndarray] | None = None
    chord: tuple[Chain, float, float] | None = None


def _frame(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray | None:
    """Columns: the primary direction, the part of the secondary across it, their cross product; None
    when the two (nearly) line up or there is no secondary."""
    x = primary / np.linalg.norm(primary)
    y = secondary - (secondary @ x) * x
    if not np.linalg.norm(y) > 0.2 * np.linalg.norm(secondary):
        return None
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def _body_turn(src: Reference, tgt: Reference) -> np.ndarray:
    """The rotation taking the target's body axes onto the source's: D above every driven joint."""
    s, t = src.body_axes(), tgt.body_axes()
    fs = np.stack([s["forward"], s["up"], s["left"]], axis=1)
    ft = np.stack([t["forward"], t["up"], t["left"]], axis=1)
    return fs @ ft.T


def _lay(spec: _Spec, carried: np.ndarray) -> np.ndarray:
    """D of a joint: from its own two directions where it has them (exact), else its parent's D
    `carried` down and swung so that the bone directions meet (the twist relative to the parent bone
    taken as the source's); the parent's D where it has no bone direction."""
    if spec.primary is None:
        return carried
    if spec.secondary is not None:
        fs, ft = _frame(spec.primary[0], spec.secondary[0]), _frame(spec.primary[1], spec.secondary[1])
        if fs is not None and ft is not None:
            return fs @ ft.T
    return rotation_between(carried @ spec.primary[1], spec.primary[0]) @ carried


def _arm_lateral(ref: Reference) -> np.ndarray | None:
    """Left arm minus right arm: each at its first point away from the joint it hangs from (rigid with
    that joint), or at the upper arms where those points coincide (clavicles starting at one place)."""
    away = []
    for side in SIDES:
        path = path_between(ref.skeleton, _attach(ref, side), ref.index(f"{side}_hand"))
        away.append(_first_away(ref, [(j, None) for j in path]))
    if away[0] is not None and away[1] is not None and np.linalg.norm(away[0] - away[1]) > TINY * ref.size:
        return away[0] - away[1]
    lateral = ref.positions[ref.index("left_upper_arm")] - ref.positions[ref.index("right_upper_arm")]
    return lateral if np.linalg.norm(lateral) > TINY * ref.size else None


def _hip_points(ref: Reference) -> list[Point | None]:
    """Left and right hip: the first point away from the pelvis down each leg."""
    pelvis = ref.index("pelvis")
    legs = [path_between(ref.skeleton, pelvis, ref.index(f"{s}_foot")) for s in SIDES]
    return [_first_point_away(ref, [(j, None) for j in leg]) for leg in legs]


def _loose_hips(ref: Reference) -> bool:
    """Whether a hip moves against the pelvis: it hangs from a joint of its own (CMU's hip joints)."""
    pelvis = ref.index("pelvis")
    return any(p is not None and int(ref.skeleton.parents[p[0]]) != pelvis for p in _hip_points(ref))


def _pelvis_pair(ref: Reference) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The pelvis's directions in one rig: across the hips (left minus right, `_hip_points`), then up
    its spine (the first point away along it)."""
    hips = _hip_points(ref)
    spine = _first_away(ref, [(j, None) for j in _central(ref)])
    across = None if None in hips else ref.at(hips[0]) - ref.at(hips[1])
    return across, spine


def _pelvis_chord(src: Reference, tgt: Reference) -> tuple[Chain, float, float] | None:
    """The source's live hip line for the target's pelvis to follow when the source's hips move against
    its pelvis and the target's do not (their line would otherwise lean as the source's pelvis does,
    not as its hips do: 2 degrees median on Xia's walks); None otherwise."""
    if not _loose_hips(src) or _loose_hips(tgt) or None in _hip_points(src):
        return None
    left, right = _hip_points(src)
    return Chain.of(src, [right, left]), 0.0, 1.0


def _hand_pair(src: Reference, tgt: Reference, side: str) -> tuple[tuple, tuple]:
    """(primary, secondary) directions of a hand both rigs give fingers, per rig: towards the first
    finger's base (middle first), then across two fingers' bases (or towards the thumb's)."""
    common = _common_fingers(src, tgt, side)
    bases = []
    for ref in (src, tgt):
        hand = (ref.index(f"{side}_hand"), None)
        bases.append(
            {f: _first_away(ref, [hand] + [(j, None) for j in _finger(ref, f"{side}_{f}")]) for f in common}
        )

    def both(*fingers: str) -> bool:
        return all(f in common and b[f] is not None for b in bases for f in fingers)

    along = next((f for f in HAND_FINGERS if both(f)), None)
    primary = (None, None) if along is None else (bases[0][along], bases[1][along])
    pair = next((p for p in FINGER_PAIRS if both(*p)), None)
    if pair is not None:
        return primary, tuple(b[pair[0]] - b[pair[1]] for b in bases)
    return primary, (bases[0]["thumb"], bases[1]["thumb"]) if both("thumb") else (None, None)


def alignment(src: Reference, tgt: Reference) -> tuple[list[Drive], list[Link]]:
    """Every driven target joint's driver and constant (see the module docstring), and the links."""
    links = _links(src, tgt)
    hubs = {"pelvis": tuple(zip(_pelvis_pair(src), _pelvis_pair(tgt)))}
    hubs |= {f"{side}_hand": _hand_pair(src, tgt, side) for side in SIDES if _hand_is_hub(src, tgt, side)}
    specs: dict[int, _Spec] = {}
    for name, (primary, secondary) in hubs.items():
        t = tgt.index(name)
        chord = _pelvis_chord(src, tgt) if name == "pelvis" and _pair(primary) is not None else None
        specs[t] = _Spec(t, src.index(name), _pair(primary), _pair(secondary), chord)
    lateral = _pair((_arm_lateral(src), _arm_lateral(tgt)))
    chest = {_attach(tgt, side) for side in SIDES}
    for link in links:
        for i in _owned(link.target, link.owns_start):
            j = link.target.points[i][0]
            if j not in specs:
                spec = _spec(src, tgt, links, link, i, lateral if chest == {j} else None)
                if spec is not None:
                    specs[j] = spec
    drives, carried = [], {}
    for j, p in enumerate(tgt.skeleton.parents):
        above = carried[int(p)] if p >= 0 else _body_turn(src, tgt)
        spec = specs.get(j)
        carried[j] = above if spec is None else _lay(spec, above)
        if spec is None:
            continue
        s = spec.source
        chord = None
        if spec.chord is not None:
            direction = src.rotations[s].T @ (spec.primary[0] / np.linalg.norm(spec.primary[0]))
            chord = (*spec.chord, direction)
        drives.append(Drive(j, s, src.rotations[s].T @ carried[j] @ tgt.rotations[j], chord))
    return drives, links


def _pair(pair) -> tuple[np.ndarray, np.ndarray] | None:
    return None if pair[0] is None or pair[1] is None else (pair[0], pair[1])


def _owned(chain: Chain, owns_start: bool) -> list[int]:
    """Indices of the chain's points whose joints it drives: all but its end (and a hub start)."""
    return list(range(0 if owns_start else 1, len(chain.points) - 1))


def _spec(src: Reference, tgt: Reference, links: list[Link], link: Link, i: int, secondary) -> _Spec | None:
    """How the target joint at point `i` of `link` is laid; None for a joint between a hub and the next
    role that the source has nothing for (CMU's hip joint against a rig whose thighs hang from the
    pelvis): it keeps its reference pose, rigid with the hub, as the source's offset is."""
    target, source = link.target, link.source
    lo, hi = target.fractions[i], target.fractions[i + 1]
    k = _driver(source, link.owns_start, lo, hi)
    if k == 0 and not link.owns_start:
        return None
    s, j = source.points[k][0], target.points[i][0]
    tiny_s, tiny_t = TINY * src.size, TINY * tgt.size
    own = (
        source.place(src, hi) - source.place(src, lo),
        tgt.at(target.points[i + 1]) - tgt.at(target.points[i]),
    )
    if np.linalg.norm(own[0]) > tiny_s and np.linalg.norm(own[1]) > tiny_t:
        same = abs(source.fractions[k] - lo) < 1e-9 and abs(source.fractions[k + 1] - hi) < 1e-9
        return _Spec(j, s, own, secondary, None if same else (source, float(lo), float(hi)))
    # No bone of its own (a joint at its child's place, a chain without an end): the whole chain's
    # direction, else the chain before it, else the parent's alignment carried over.
    for c in [link] + ([links[link.previous]] if link.previous is not None else []):
        whole = (
            src.at(c.source.points[-1]) - src.at(c.source.points[0]),
            tgt.at(c.target.points[-1]) - tgt.at(c.target.points[0]),
        )
        if np.linalg.norm(whole[0]) > tiny_s and np.linalg.norm(whole[1]) > tiny_t:
            return _Spec(j, s, whole, secondary)
    return _Spec(j, s, None)


def _driver(source: Chain, owns_start: bool, lo: float, hi: float) -> int:
    """The source point whose segment covers most of [lo, hi] (the nearest on ties); the chain's start
    when the source has no driven segment on it."""
    segments = _owned(source, owns_start)
    if not segments:
        return 0
    a = source.fractions

    def score(k: int) -> float:
        overlap = min(hi, a[k + 1]) - max(lo, a[k])
        return max(overlap, 0.0) - 1e-3 * abs((a[k] + a[k + 1]) / 2 - (lo + hi) / 2)

    return max(segments, key=score)
