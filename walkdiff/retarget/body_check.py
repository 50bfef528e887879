"""Whether a rig stands like a biped, measured on its posed frames.

Retargeting moves a human body: a rig whose joints carry human names (a quadruped exported with Biped
bone names, its front legs on the UpperArm chain) but whose body stands otherwise is refused before any
motion is moved, with what was measured. Up is the way from the feet to the pelvis, at its median over
the clip (legs hold the pelvis up in any standing body, whatever axis the file calls up). A biped has:

- its spine (pelvis to neck, or head) within SPINE_DEGREES of up on its most upright frames (the UPRIGHT
  percentile over the frames: people bend over, a quadruped's spine never rises);
- its hands, at the median, at least HANDS_UP of a leg's length above the floor under the feet (arms
  that reach the floor carry the body);
- legs (thigh to foot along the bones) no shorter than its arms (upper arm to hand);
- its feet the lowest points: at the median, no joint outside the legs more than BELOW of a leg's length
  below them (joints above the pelvis, a static root on the floor, are no part of the body).

Crawling, a handstand or a clip of someone lying down are refused too: `--force` (force=True) retargets
them as before.
"""

from __future__ import annotations

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.humanoid import SIDES, HumanoidMap, leg_length, path_between
from walkdiff.motion.posed_frames import subtree, world_transforms
from walkdiff.motion.skeleton import Motion, Skeleton

SPINE_DEGREES = 60.0
UPRIGHT = 10  # percentile of the spine's angles over the frames: its most upright
HANDS_UP = 0.25
BELOW = 0.1


def _length(skeleton: Skeleton, top: str, bottom: str) -> float:
    """Along the bones from joint `top` down to `bottom`."""
    chain = path_between(skeleton, skeleton.index(top), skeleton.index(bottom))
    return float(sum(np.linalg.norm(skeleton.offsets[j]) for j in chain[1:]))


def check_body(motion: Motion, hmap: HumanoidMap, which: str, most: int = 300) -> None:
    """Refuse a rig whose clip (its frames, `most` of them spread over it) does not stand like a biped:
    one WalkdiffError naming `which` rig, what was measured and the joints."""
    step = max(1, motion.num_frames // most)
    positions, _ = world_transforms(
        Motion(motion.skeleton, motion.rotations[::step], motion.positions[::step], motion.frame_time)
    )
    problems = body_problems(positions, motion.skeleton, hmap)
    if problems:
        raise WalkdiffError(
            f"retarget: {which} does not stand like a biped: {'; '.join(problems)}; `walkdiff retarget "
            "--force` (force=True) retargets it anyway"
        )


def body_problems(positions: np.ndarray, skeleton: Skeleton, hmap: HumanoidMap) -> list[str]:
    """What makes the body of world `positions` (F, J, 3; any axes and units) no standing biped, each
    with what was measured and the joints; empty for a biped."""
    pelvis = skeleton.index(hmap.pelvis)
    feet = [skeleton.index(hmap.joint(f"{s}_foot")) for s in SIDES]
    legs = {j for s in SIDES for j in subtree(skeleton, skeleton.index(hmap.joint(f"{s}_thigh")))}
    soles = sorted({j for f in feet for j in subtree(skeleton, f)})  # feet, toes and below
    # One up for the clip: a crouch or a lean tilts the pelvis over the feet on some frames, not the floor.
    up = np.median(positions[:, pelvis] - positions[:, feet].mean(axis=1), axis=0)
    if np.linalg.norm(up) < 1e-9:
        return [f"its pelvis {hmap.pelvis} is level with its feet"]
    up = up / np.linalg.norm(up)
    heights = positions @ up
    floor = heights[:, soles].min(axis=1)
    leg, arm = (
        leg_length(skeleton, hmap),
        np.mean([_length(skeleton, hmap.joint(f"{s}_upper_arm"), hmap.joint(f"{s}_hand")) for s in SIDES]),
    )
    problems = []
    top = hmap.neck or hmap.head
    spine = positions[:, skeleton.index(top)] - positions[:, pelvis]
    cosine = spine @ up / np.maximum(np.linalg.norm(spine, axis=1), 1e-12)
    # Its most upright frames: Xia's old man walks bent over 58 deg at the median, 50 at his most upright.
    angle = float(np.percentile(np.degrees(np.arccos(np.clip(cosine, -1, 1))), UPRIGHT))
    if angle > SPINE_DEGREES:
        problems.append(
            f"its spine ({hmap.pelvis} to {top}) is {angle:.0f} deg from up even at its most upright "
            f"({UPRIGHT:.0f}th percentile; up: the way from the feet to the pelvis; a biped's is within "
            f"{SPINE_DEGREES:.0f})"
        )
    hands = [hmap.joint(f"{s}_hand") for s in SIDES]
    raised = float(np.median(heights[:, [skeleton.index(h) for h in hands]].min(axis=1) - floor)) / leg
    if raised < HANDS_UP:
        problems.append(
            f"its hands ({', '.join(hands)}) are {raised:.0%} of a leg above the floor: the arms carry the "
            f"body (a biped's hands are at least {HANDS_UP:.0%} up)"
        )
    if leg < arm:
        problems.append(
            f"its legs ({hmap.left_thigh} to {hmap.left_foot}, {leg:.3g} units) are shorter than its arms "
            f"({hmap.left_upper_arm} to {hmap.left_hand}, {arm:.3g})"
        )
    body = [j for j in subtree(skeleton, pelvis) if j not in legs]
    lowest = heights[:, body].min(axis=1) - floor
    below = float(np.median(lowest)) / leg
    if below < -BELOW:
        joint = skeleton.names[body[int(np.bincount(np.argmin(heights[:, body], axis=1)).argmax())]]
        problems.append(
            f"its feet are not its lowest points: {joint} is {-below:.0%} of a leg below them (a biped's "
            f"feet are, within {BELOW:.0%})"
        )
    return problems
