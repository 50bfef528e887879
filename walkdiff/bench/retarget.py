"""`walkdiff bench retarget`: retargeting measured against the numbers of issue 29.

Four kinds of pairs, each over the same real clips (Xia clips of different styles and contents):

- same proportions (`walkdiff.bench.rig_variants`): the clip's own rig with another rest pose, random
  local frames, another rotation order, up axis and units. The answer is known: world joint positions
  within 0.5% of body height, and back again (A -> B -> A) as close.
- other proportions (legs 0.8x and 1.25x, arms 1.2x, a longer spine, hips 0.6x and 1.6x as wide, a
  big character: 1.5x, 2 m from Xia's 1.36 m, hips 1.3x as wide): bone directions within 2 deg
  median and 5 deg p95 (the legs measured with the foot IK off, which bends them on purpose), hands and
  feet turned within 10 deg, the root's path the source's times the leg ratio within 1%, feet planted.
- real pairs: Xia onto ZEGGS (its first frame as the reference) and back, ZEGGS onto Xia, Xia onto each
  built-in rig.
- circling (issue 46): the clips that travel (walks and runs) walked round a 2 m circle
  (`walkdiff.bench.circle_walk`), onto a big character of another hip-width-to-leg ratio (the built-in
  mixamo rig 2 m tall, hips 1.4x) and onto ZEGGS; and the big character's clip at 60 fps as the source,
  onto Xia and ZEGGS.

Every pair's legs with the foot IK on: the worst leg bone within 3 deg of the source's at its median
(issue 46: the feet may bend a leg away only as far as a contact needs).

Bone directions are read pooled over the bones (as tests/test_retarget.py does) and per bone (the worst
bone's own median and p95). Feet on every pair: the project's skate ratio as its evaluator measures it
(`ground_skating`) with the target's own profile, at most 1.1x the source's; contact frames
kept (two readings, see `CONTACT_READINGS`); no contact joint below its floor (the 5th percentile of
its planted heights) by more than 1% of body height. Speed: a prepared `Retargeter` on one clip,
10,000 frames/s or more; a one-shot call reported beside it. Positions are in body heights
(`SkeletonProfile.body_height`), directions in degrees.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from walkdiff.bench.circle_walk import circled, travels
from walkdiff.bench.measure import machine, median_seconds
from walkdiff.bench.retarget_report import checks, summary
from walkdiff.bench.rig_variants import (
    arms,
    axes_and_units,
    hips,
    legs,
    longer_spine,
    random_frames,
    reposed,
    rotation_order,
    scaled,
)
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_json
from walkdiff.common.progress import progress
from walkdiff.metrics.physics import skating_sums
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.humanoid import SIDES, humanoid_map
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.profile import ContactSpec, SkeletonProfile
from walkdiff.motion.representation import contact_state
from walkdiff.motion.resample import resample
from walkdiff.motion.skeleton import Motion
from walkdiff.retarget.retargeter import Retargeter
from walkdiff.retarget.rigs import RIGS, rig

# Bones (role to role) whose world direction must follow the source's; the legs' two long bones are
# bent by the foot IK when the proportions differ, and measured without it (LEGS).
BONES = [
    ("left_clavicle", "left_upper_arm"), ("left_upper_arm", "left_forearm"), ("left_forearm", "left_hand"),
    ("left_foot", "left_toe"), ("neck", "head"), ("pelvis", "neck"), ("left_thigh", "right_thigh"),
    ("left_upper_arm", "right_upper_arm"),
]  # fmt: skip
BONES += [(a.replace("left", "right"), b.replace("left", "right")) for a, b in BONES if "right" not in b]
LEGS = [(f"{s}_{a}", f"{s}_{b}") for s in SIDES for a, b in (("thigh", "shin"), ("shin", "foot"))]
HANDS_AND_FEET = tuple(f"{s}_{p}" for s in SIDES for p in ("hand", "foot"))
Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +Y -> +Z, x kept

TARGETS = {
    "position_error_max": "same proportions: world joint positions within 0.5% of body height",
    "round_trip_max": "same proportions: A -> B -> A within 0.5% of body height",
    "bones_median_deg / bones_p95_deg": "every mapped bone's world direction within 2 deg median, 5 p95 "
    "(all bones' angles pooled, as tests/test_retarget.py reads it)",
    "bones_worst_median_deg / bones_worst_p95_deg": "the same per bone: the worst bone's own median and p95",
    "legs_free_median_deg / legs_free_p95_deg": "the legs' bones, foot IK off: the same bounds",
    "legs_with_ik_worst_median_deg": "foot IK on: the worst leg bone's median within 3 deg (issue 46)",
    "hands_feet_turn_max_deg": "hand and foot orientation within 10 deg (other proportions)",
    "skate_ratio": "foot skating on the target (the project's skate ratio, `ground_skating`, with the "
    "target's own profile) <= 1.1x the source's (with the source's profile)",
    "contacts_kept_own / contacts_kept_scaled": "contact frames kept >= 98%",
    "below_floor": "feet below their floor by <= 1% of body height",
    "path_length_error": "root path length = source's x leg ratio within 1%",
    "sides_kept": "no left/right swap on any pair",
    "frames_per_s": ">= 10,000 frames/s, one clip, a prepared Retargeter, 2 CPU cores",
}
CONTACT_READINGS = {
    "contacts_kept_own": "contacts detected on the target with the target's own profile (its contact "
    "joints, speed and height thresholds from its legs' length), share of the source's contact frames kept",
    "contacts_kept_scaled": "contacts detected on the target's retargeted contact joints with the source's "
    "thresholds times the leg ratio, share of the source's contact frames kept",
}
# Figures without a target of their own, and what they are for.
READINGS = {
    "skate_ratio_scaled": "the target's skate ratio with the source's thresholds times the leg ratio on its "
    "retargeted contact joints (the same as its own profile's since those go with the legs' length)",
    "legs_with_ik_*": "the legs' bone directions with the foot IK on (it bends them on purpose)",
    "below_floor_source": "the source's own feet below their floor, body heights",
    "slide_speed*": "mean horizontal speed of ground contacts, body heights/s",
    "one_shot_frames_per_s": "a Retargeter made and run once (the per-rig work included)",
    "frames_per_s_torch_1_thread": "the prepared Retargeter with torch on 1 thread (its contact detection "
    "runs in torch: on a 2-core machine busy with other work, 2-thread torch calls wait for the busy core)",
}


# ---------------------------------------------------------------- measures


def world(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    return forward_kinematics(
        motion.rotations, motion.positions, motion.skeleton.parents, return_rotations=True
    )


def position_error(a: Motion, b: Motion, height: float) -> np.ndarray:
    """(F, J) distances between the same joints (by name) of two clips, in body heights `height`."""
    pa, pb = world(a)[0], world(b)[0]
    names = [n for n in a.skeleton.names if n in b.skeleton.names]
    ia, ib = [a.skeleton.index(n) for n in names], [b.skeleton.index(n) for n in names]
    return np.linalg.norm(pa[:, ia] - pb[:, ib], axis=-1) / height


def degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def canonical_points(motion: Motion) -> np.ndarray:
    """(F, J, 3) world joint positions, Y up (the clip's profile's turn)."""
    return world(motion)[0] @ SkeletonProfile.detect(motion.slice(0, 1)).turn.T


def bone_angles(source: Motion, target: Motion, bones=BONES) -> list[tuple[str, np.ndarray]]:
    """('a-b', (F,) angles) between the world directions of the same role-to-role bones (canonical
    axes); bones whose roles either rig lacks (a neck, a toe) are left out."""
    ms, mt = humanoid_map(source), humanoid_map(target)
    ps, pt = canonical_points(source), canonical_points(target)
    out = []
    for a, b in bones:
        if None in (ms.joint(a), ms.joint(b), mt.joint(a), mt.joint(b)):
            continue
        js = [source.skeleton.index(ms.joint(r)) for r in (a, b)]
        jt = [target.skeleton.index(mt.joint(r)) for r in (a, b)]
        out.append((f"{a}-{b}", degrees(pt[:, jt[1]] - pt[:, jt[0]], ps[:, js[1]] - ps[:, js[0]])))
    return out


def bone_errors(source: Motion, target: Motion, bones=BONES) -> np.ndarray:
    """(F, bones) angles of `bone_angles`, in the order of `bones`."""
    return np.stack([angles for _, angles in bone_angles(source, target, bones)], axis=1)


def turn_degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles of the rotations taking each of `b` (..., 3, 3) to `a`."""
    trace = np.trace(a @ np.swapaxes(b, -1, -2), axis1=-2, axis2=-1)
    return np.degrees(np.arccos(np.clip((trace - 1) / 2, -1.0, 1.0)))


def sides_kept(source: Motion, target: Motion, ratio: float) -> bool:
    """Every left hand and foot of the target nearer the source's same joint (scaled) than the other's."""
    ms, mt = humanoid_map(source), humanoid_map(target)
    ps, pt = canonical_points(source) * ratio, canonical_points(target)
    for part in ("hand", "foot"):
        for side, other in (("left", "right"), ("right", "left")):
            t = pt[:, target.skeleton.index(mt.joint(f"{side}_{part}"))]
            same, swapped = (ps[:, source.skeleton.index(ms.joint(f"{s}_{part}"))] for s in (side, other))
            if np.mean(np.linalg.norm(t - same, axis=1)) >= np.mean(np.linalg.norm(t - swapped, axis=1)):
                return False
    return True


def foot_sums(motion: Motion, contacts: np.ndarray, profile: SkeletonProfile | None = None) -> np.ndarray:
    """[contact steps, skating steps, summed horizontal contact speed (units/s), deepest below the floor
    (units)] of `motion`'s contact joints (its profile's) over `contacts` (F, 4). A joint's floor is the
    5th percentile of its planted heights; NaN depth when nothing is planted."""
    profile = profile or SkeletonProfile.detect(motion)
    feet = [motion.skeleton.index(n) for n in profile.contacts.joints]
    positions = torch.tensor(world(motion)[0] @ profile.turn.T)[None]
    steps, skating, speed = skating_sums(
        positions, torch.tensor(contacts)[None], feet, motion.fps, profile.contact_speed
    )
    heights = positions[0, :, feet, 1].numpy()
    planted = contacts > 0.5
    depths = [
        float((np.percentile(heights[planted[:, i], i], 5) - heights[:, i]).max())
        for i in range(4)
        if planted[:, i].any()
    ]
    return np.array([float(steps), float(skating), float(speed), max(depths, default=np.nan)])


def foot_measures(motion: Motion, contacts: np.ndarray, height: float) -> tuple[float, float, float]:
    """The project's skate ratio (its own profile's speed threshold) and mean horizontal slide speed (body
    heights/s) over the given contacts, and how far any contact joint goes below the level it is planted
    at, in body heights."""
    steps, skating, speed, below = foot_sums(motion, contacts)
    return float(skating / steps), float(speed / steps) / height, below / height


def ground_skating(motion: Motion, spec: ContactSpec) -> np.ndarray:
    """[contact steps, skating steps, summed horizontal contact speed (units/s)]: the project's skate ratio
    as its evaluator measures it (`MotionScorer.ground_contacts`): a foot joint touches the ground when
    within `spec`'s contact height of its floor (the 5th percentile of its heights), whatever its speed,
    and skates when faster along the ground than `spec`'s contact speed."""
    feet = [motion.skeleton.index(n) for n in spec.joints]
    points = canonical_points(motion)
    low, _ = contact_state(points[:, feet], motion.fps, spec)
    steps, skating, speed = skating_sums(
        torch.tensor(points)[None], torch.tensor(low)[None], feet, motion.fps, spec.speed_threshold
    )
    return np.array([float(steps), float(skating), float(speed)])


def path_length(motion: Motion, joint: str) -> float:
    """The horizontal length of `joint`'s path (canonical axes)."""
    points = canonical_points(motion)[:, motion.skeleton.index(joint)]
    return float(np.linalg.norm(np.diff(points[:, [0, 2]], axis=0), axis=1).sum())


def detect_contacts(motion: Motion, spec: ContactSpec) -> np.ndarray:
    """(F, 4) bool: `spec`'s joints in contact, heights measured up the clip's own up axis."""
    joints = [motion.skeleton.index(n) for n in spec.joints]
    low, slow = contact_state(canonical_points(motion)[:, joints], motion.fps, spec)
    return low & slow


# ---------------------------------------------------------------- figures


def _round(value: float) -> float:
    return float(f"{value:.4g}") if np.isfinite(value) else float("nan")


def _check(value: float, op: str, bound: float, target: str | None = None) -> dict:
    ok = value <= bound if op == "<=" else value >= bound
    return {"value": _round(value), "target": target or f"{op} {bound:g}", "pass": bool(ok)}


@dataclass
class SamePool:
    """A same-proportions case pooled over clips: position errors there and back, body heights."""

    there: list = field(default_factory=list)
    back: list = field(default_factory=list)

    def figures(self) -> dict:
        there, back = np.concatenate(self.there, axis=None), np.concatenate(self.back, axis=None)
        return {
            "position_error_max": _check(there.max(), "<=", 0.005),
            "position_error_mean": _round(there.mean()),
            "round_trip_max": _check(back.max(), "<=", 0.005),
            "round_trip_mean": _round(back.mean()),
        }


def _worst_bones(per_bone: dict[str, np.ndarray]) -> dict:
    """Each bone's own median and p95, and the worst bone of each: "every mapped bone" read per bone
    (the pooled figures above it let a bone that is always off hide among exact ones)."""
    figures = {n: (float(np.median(a)), float(np.percentile(a, 95))) for n, a in per_bone.items()}
    median, p95 = (max(figures, key=lambda n, k=k: figures[n][k]) for k in (0, 1))
    return {
        "bones_worst_median_deg": {**_check(figures[median][0], "<=", 2.0), "bone": median},
        "bones_worst_p95_deg": {**_check(figures[p95][1], "<=", 5.0), "bone": p95},
        "per_bone_median_p95_deg": {n: [_round(m), _round(p)] for n, (m, p) in figures.items()},
    }


def _worst_leg(per_bone: dict[str, np.ndarray]) -> dict:
    """The leg bone (foot IK on) furthest from the source's directions at its median: the feet may bend
    a leg away only as far as a contact needs (issue 46 saw a thigh 9.7 deg off on other hip widths)."""
    medians = {n: float(np.median(a)) for n, a in per_bone.items()}
    worst = max(medians, key=medians.get)
    return {"legs_with_ik_worst_median_deg": {**_check(medians[worst], "<=", 3.0), "bone": worst}}


@dataclass
class PairPool:
    """A retargeting pair's measures pooled over clips (see the module docstring)."""

    orientation: bool = False  # hands and feet comparable joint by joint (a copy of the source's rig)
    bones: list = field(default_factory=list)
    per_bone: dict = field(default_factory=dict)  # 'a-b' -> its angles per clip
    legs_ik: list = field(default_factory=list)
    per_leg: dict = field(default_factory=dict)  # 'thigh-shin' ... -> its angles per clip, foot IK on
    legs_free: list = field(default_factory=list)
    turns: list = field(default_factory=list)
    paths: list = field(default_factory=list)
    # Ground skating sums (steps, skating steps, speed in body heights/s) of the source (its profile), the
    # target (its own profile) and the target with the source's thresholds times the leg ratio.
    skating: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    below: list = field(default_factory=list)  # (source, target) in body heights
    kept: np.ndarray = field(default_factory=lambda: np.zeros(3))  # source contacts, own kept, scaled kept
    sides: list = field(default_factory=list)
    ratios: list = field(default_factory=list)

    def add(self, source: Motion, retargeter: Retargeter, free: Motion | None) -> Motion:
        """Measure `retargeter` on `source` (`free`: the same with the foot IK off); the retargeted clip."""
        result = retargeter(source)
        out, ratio, contacts = result.motion, result.leg_ratio, result.contacts
        sp, tp = retargeter.source_profile, SkeletonProfile.detect(out)
        self.ratios.append(ratio)
        angles = bone_angles(source, out)
        self.bones.append(np.stack([a for _, a in angles], axis=1))
        for name, a in dict(angles).items():
            self.per_bone.setdefault(name, []).append(a)
        self.legs_ik.append(bone_errors(source, out, LEGS))
        for name, a in bone_angles(source, out, LEGS):
            self.per_leg.setdefault(name, []).append(a)
        self.legs_free.append(bone_errors(source, free if free is not None else out, LEGS))
        ms, mt = retargeter.source_map, retargeter.target_map
        if self.orientation:
            ws, wt = world(source)[1], world(out)[1]
            for role in HANDS_AND_FEET:
                js, jt = source.skeleton.index(ms.joint(role)), out.skeleton.index(mt.joint(role))
                self.turns.append(turn_degrees(wt[:, jt], ws[:, js]))
        expected = path_length(source, ms.pelvis) * ratio
        self.paths.append(abs(path_length(out, mt.pelvis) / expected - 1) if expected > 0 else np.nan)
        names = [out.skeleton.names[j] for j in retargeter.target_feet]
        scaled = ContactSpec(
            *names, speed_threshold=sp.contact_speed * ratio, height_threshold=sp.contact_height * ratio
        )
        readings = ((source, sp.contacts, sp.body_height), (out, tp.contacts, tp.body_height))
        for row, (motion, spec, height) in enumerate((*readings, (out, scaled, sp.body_height * ratio))):
            self.skating[row] += ground_skating(motion, spec) / [1, 1, height]
        below = [foot_sums(m, contacts, p)[3] / p.body_height for m, p in ((source, sp), (out, tp))]
        self.below.append(below)
        planted = contacts > 0.5
        self.kept += [
            planted.sum(),
            (detect_contacts(out, tp.contacts) & planted).sum(),
            (detect_contacts(out, scaled) & planted).sum(),
        ]
        self.sides.append(sides_kept(source, out, ratio))
        return out

    def figures(self) -> dict:
        bones, legs_ik, legs_free = (np.concatenate(x) for x in (self.bones, self.legs_ik, self.legs_free))
        skate_s, skate_t, skate_scaled = self.skating[:, 1] / np.maximum(self.skating[:, 0], 1)
        slide_s, slide_t, _ = self.skating[:, 2] / np.maximum(self.skating[:, 0], 1)
        below = np.array(self.below)
        figures = {
            "leg_ratio": _round(float(np.mean(self.ratios))),
            "bones_median_deg": _check(np.median(bones), "<=", 2.0),
            "bones_p95_deg": _check(np.percentile(bones, 95), "<=", 5.0),
            **_worst_bones({name: np.concatenate(a) for name, a in self.per_bone.items()}),
            "legs_free_median_deg": _check(np.median(legs_free), "<=", 2.0),
            "legs_free_p95_deg": _check(np.percentile(legs_free, 95), "<=", 5.0),
            "legs_with_ik_median_deg": _round(np.median(legs_ik)),
            "legs_with_ik_p95_deg": _round(np.percentile(legs_ik, 95)),
            **_worst_leg({name: np.concatenate(a) for name, a in self.per_leg.items()}),
        }
        if self.turns:
            figures["hands_feet_turn_max_deg"] = _check(np.concatenate(self.turns).max(), "<=", 10.0)
        figures |= {
            "path_length_error": _check(np.nanmax(self.paths), "<=", 0.01),
            "skate_ratio_source": _round(skate_s),
            "skate_ratio": _check(skate_t, "<=", 1.1 * skate_s, f"<= 1.1 x source = {1.1 * skate_s:.4g}"),
            "skate_ratio_scaled": _round(skate_scaled),
            "slide_speed_source": _round(slide_s),
            "slide_speed": _round(slide_t),
            "contact_frames_source": int(self.kept[0]),
            "contacts_kept_own": _check(self.kept[1] / max(self.kept[0], 1), ">=", 0.98),
            "contacts_kept_scaled": _check(self.kept[2] / max(self.kept[0], 1), ">=", 0.98),
            "below_floor_source": _round(np.nanmax(below[:, 0])),
            "below_floor": _check(np.nanmax(below[:, 1]), "<=", 0.01),
            "sides_kept": {"value": all(self.sides), "target": "no swap", "pass": all(self.sides)},
        }
        return figures


# ---------------------------------------------------------------- cases


def _same_proportions(clip: Motion, seed: int) -> dict[str, tuple]:
    """Name -> (the variant (its world positions the source's, turned and scaled), what the retargeter
    is given as the target, the scale, written to BVH and read back)."""
    metres = SkeletonProfile.detect(clip).metres_per_unit
    a_pose = reposed(clip)
    heap = random_frames(clip, seed)
    order = rotation_order(clip, "XYZ")
    z_up = axes_and_units(a_pose, Z_UP, metres)
    everything = axes_and_units(rotation_order(random_frames(a_pose, seed), "XYZ"), Z_UP, 100 * metres)
    return {
        "A pose, legs re-posed (rest pose)": (a_pose, a_pose.skeleton, 1.0, False),
        "random local frames (frame 0)": (heap, heap, 1.0, False),
        "rotation order XYZ, via a BVH file": (order, order.skeleton, 1.0, True),
        "Z up, metres by its profile, A pose (rest pose)": (z_up, z_up.skeleton, metres, False),
        "all: random frames, A pose, XYZ, Z up, cm (frame 0)": (everything, everything, 100 * metres, False),
    }


OTHER_PROPORTIONS = {
    "legs 0.8x": lambda s: legs(s, 0.8),
    "legs 1.25x": lambda s: legs(s, 1.25),
    "arms 1.2x": lambda s: arms(s, 1.2),
    "longer spine (+2 joints)": longer_spine,
    # Other hip-width-to-leg ratios (issue 46: feet on the source's scaled path pulled thighs out of line).
    "hips 0.6x": lambda s: hips(s, 0.6),
    "hips 1.6x": lambda s: hips(s, 1.6),
    "big: 1.5x, hips 1.3x": lambda s: hips(scaled(s, s.names, 1.5), 1.3),  # a 2 m character from Xia's
}


def _run_same(clip: Motion, seed: int, height: float, pools: dict, folder: Path) -> None:
    for name, (variant, given, scale, via_file) in _same_proportions(clip, seed).items():
        out = Retargeter(clip, given)(clip).motion
        if via_file:
            write_bvh(folder / "variant.bvh", out)
            out = read_bvh(folder / "variant.bvh")
        back = Retargeter(out, clip.skeleton)(out).motion
        pool = pools.setdefault(name, SamePool())
        pool.there.append(position_error(out, variant, scale * height))
        pool.back.append(position_error(back, clip, height))


def _run_other(clip: Motion, pools: dict) -> None:
    for name, change in OTHER_PROPORTIONS.items():
        skeleton = change(clip.skeleton)
        free = Retargeter(clip, skeleton, feet="off")(clip).motion
        pools.setdefault(name, PairPool(orientation=True)).add(clip, Retargeter(clip, skeleton), free)


def _pair(source: Motion, target, pools: dict, name: str) -> Motion:
    """Retarget `source` onto `target` into the pool `name`; the retargeted clip."""
    free = Retargeter(source, target, feet="off")(source).motion
    return pools.setdefault(name, PairPool()).add(source, Retargeter(source, target), free)


CIRCLE_RADIUS_M = 2.0
BIG_HEIGHT_M, BIG_HIPS, BIG_FPS = 2.0, 1.4, 60.0
BIG = f"big = mixamo {BIG_HEIGHT_M:g} m, hips {BIG_HIPS:g}x, at {BIG_FPS:g} fps as a source"


def _run_circling(clip: Motion, window: Motion | None, sign: float, pools: dict) -> None:
    """The clip walking round a circle (`circle_walk.circled`), onto a big character of another
    hip-width-to-leg ratio (BIG: the built-in mixamo rig, 2 m tall, its hips wider) and onto ZEGGS;
    and the big character's clip, at 60 fps, as the source: onto Xia and ZEGGS (issue 46's 2 m Mixamo
    walking in a circle bent Xia's thighs 9.7 deg away from its own)."""
    circle = circled(clip, CIRCLE_RADIUS_M, sign)
    big = hips(rig("mixamo", BIG_HEIGHT_M).skeleton, BIG_HIPS)
    foreign = resample(_pair(circle, big, pools, "xia -> big"), BIG_FPS)
    _pair(foreign, clip.slice(0, 1), pools, "big -> xia")
    if window is not None:
        _pair(circle, window.slice(0, 1), pools, "xia -> zeggs")
        _pair(foreign, window.slice(0, 1), pools, "big -> zeggs")


def _run_real(clip: Motion, window: Motion | None, height: float, pools: dict, trips: list) -> None:
    for name in RIGS:
        _pair(clip, rig(name), pools, f"xia -> {name}")
    if window is None:
        return
    on_zeggs = _pair(clip, window.slice(0, 1), pools, "xia -> zeggs")
    back = Retargeter(on_zeggs, clip.slice(0, 1))(on_zeggs).motion
    trips.append(position_error(back, clip, height))
    _pair(window, clip.slice(0, 1), pools, "zeggs -> xia")


def _speed(clip: Motion, zeggs: Motion | None, repeats: int) -> dict:
    """Frames/s of a prepared Retargeter (median of `repeats`) and of a one-shot call, per target."""
    targets = {"legs 1.25x (foot IK at work)": legs(clip.skeleton, 1.25), "mixamo": rig("mixamo")}
    if zeggs is not None:
        targets["zeggs"] = zeggs.slice(0, 1)
    rows: dict = {"load_average_1min": _round(os.getloadavg()[0]), "torch_threads": torch.get_num_threads()}
    for name, target in targets.items():
        prepared = Retargeter(clip, target)
        prepared(clip)  # warm
        seconds = median_seconds(lambda p=prepared: p(clip), repeats)
        once = median_seconds(lambda t=target: Retargeter(clip, t)(clip), max(1, repeats // 3))
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            single = median_seconds(lambda p=prepared: p(clip), repeats)
        finally:
            torch.set_num_threads(threads)
        rows[name] = {
            "frames_per_s": _check(clip.num_frames / seconds, ">=", 10_000),
            "one_shot_frames_per_s": _round(clip.num_frames / once),
            "frames_per_s_torch_1_thread": _round(clip.num_frames / single),
        }
    return rows


# ---------------------------------------------------------------- the benchmark


def load_clips(data: str | Path | None, count: int) -> tuple[dict[str, Motion], tuple[str, Motion]]:
    """`count` Xia clips of different styles and contents (the i-th: style i mod 8 and content group i
    mod 6, the first such file by name), and the first ZEGGS take; from the data root `data`
    (default $WALKDIFF_DATA, else ./data)."""
    from walkdiff.common.paths import dataset_dir
    from walkdiff.data.xia import GROUPS, STYLES, list_clips

    xia = list_clips(dataset_dir("xia", data))
    if count > len(xia):
        raise WalkdiffError(f"bench retarget: --clips {count}: the Xia folder has {len(xia)} clips")
    picked = []
    for i in range(count):
        left = [c for c in xia if c not in picked]
        kind = [c for c in left if c.style == i % len(STYLES) and c.content == i % len(GROUPS)]
        picked.append((kind or left)[0])
    folder = dataset_dir("zeggs", data)
    takes = sorted(folder.glob("*.bvh"))
    if not takes:
        raise WalkdiffError("bench retarget: no ZEGGS take (.bvh) found", path=folder)
    return {c.name: read_bvh(c.path) for c in picked}, (takes[0].stem, read_bvh(takes[0]))


def zeggs_windows(zeggs: Motion, count: int, frames: int) -> list[Motion]:
    """`count` windows of `frames` frames spread evenly over a take."""
    frames = min(frames, zeggs.num_frames)
    starts = np.linspace(0, zeggs.num_frames - frames, count).round().astype(int)
    return [zeggs.slice(int(s), int(s) + frames) for s in starts]


def bench_retarget(
    clips: dict[str, Motion],
    zeggs: tuple[str, Motion] | None,
    out: str | Path,
    *,
    frames: int = 300,
    repeats: int = 9,
) -> dict:
    """Every case over `clips` (name -> clip, each cut to `frames`), ZEGGS windows of the take `zeggs`
    (name, clip) when given; writes the JSON `out`, prints a summary and returns the result."""
    if not clips:
        raise WalkdiffError("bench retarget: no clips to measure")
    started = time.perf_counter()
    clips = {name: clip.slice(0, frames) for name, clip in clips.items()}
    windows = zeggs_windows(zeggs[1], len(clips), frames) if zeggs else [None] * len(clips)
    first = next(iter(clips.values()))
    speed = _speed(first, zeggs and zeggs[1], repeats)  # first: the machine is at its quietest
    same, other, real, circling, trips, heights, circling_clips = {}, {}, {}, {}, [], {}, []
    with tempfile.TemporaryDirectory() as folder:
        for seed, (name, clip) in enumerate(progress(clips.items(), desc="retarget clips", unit="clip")):
            height = heights[name] = SkeletonProfile.detect(clip).body_height
            _run_same(clip, seed, height, same, Path(folder))
            _run_other(clip, other)
            _run_real(clip, windows[seed], height, real, trips)
            if travels(clip):  # walks and runs go round a circle, one way then the other
                _run_circling(clip, windows[seed], (-1.0) ** len(circling_clips), circling)
                circling_clips.append(name)
    real_figures = {name: pool.figures() for name, pool in real.items()}
    if trips:
        trip = np.concatenate(trips, axis=None)
        real_figures["xia -> zeggs -> xia"] = {
            "round_trip_max": _round(trip.max()),
            "round_trip_mean": _round(trip.mean()),
            "note": "no target in the issue (its 0.5% is for same proportions): ZEGGS has no joints for "
            "Xia's LHipJoint/RHipJoint, which come back rigid with a pelvis that carried their turn, one "
            "spine joint more, and its body went lower where its legs could not reach Xia's pushing off",
        }
    result = {
        "benchmark": "retarget",
        "clips": [
            {"name": n, "frames": c.num_frames, "fps": round(c.fps, 3), "body_height": round(heights[n], 4)}
            for n, c in clips.items()
        ],
        "zeggs": None if zeggs is None else {"take": zeggs[0], "windows": len(windows), "frames": frames},
        "targets": TARGETS,
        "contacts_kept_readings": CONTACT_READINGS,
        "readings": READINGS,
        "units": "positions in body heights (SkeletonProfile.body_height of each clip), angles in degrees, "
        "slide speeds in body heights/s",
        "same_proportions": {name: pool.figures() for name, pool in same.items()},
        "other_proportions": {name: pool.figures() for name, pool in other.items()},
        "real_pairs": real_figures,
        "circling": {name: pool.figures() for name, pool in circling.items()},
        "circling_clips": {
            "clips": circling_clips,
            "radius_m": CIRCLE_RADIUS_M,
            "big": BIG,
            "note": "the clips that travel (walks and runs: circle_walk.travels), each walked round a "
            "circle of this radius, turning left and right in turn (circle_walk.circled)",
        },
        "speed": {"clip": next(iter(clips)), "frames": first.num_frames, **speed},
        "machine": machine(),
    }
    result["checks"] = checks(result)
    result["seconds"] = round(time.perf_counter() - started, 1)
    write_json(out, result)
    print("\n".join(summary(result)))
    return result
