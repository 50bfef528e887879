"""Rigs that are not humanoids, made by the tests: a quadruped exported with 3ds Max Biped bone names (its
front legs on the UpperArm chain, its spine horizontal) and a crab (eye stalks, claws and eight legs).
Each walks a few steps on the floor: the body check must refuse them from their posed frames."""

from __future__ import annotations

import numpy as np

from walkdiff.motion.rotations import euler_to_matrix
from walkdiff.motion.skeleton import Motion, Skeleton

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")


def _mirrored(joints: list[tuple[str, str | None, tuple]]) -> list[tuple[str, str | None, tuple]]:
    """Each joint with an L in its name followed by its R copy (x negated, parents renamed)."""
    out = []
    for name, parent, offset in joints:
        out.append((name, parent, offset))
        if "_L_" in name:
            other = None if parent is None else parent.replace("_L_", "_R_")
            out.append((name.replace("_L_", "_R_"), other, (-offset[0], offset[1], offset[2])))
    return out


def _skeleton(joints) -> Skeleton:
    names = [j[0] for j in joints]
    return Skeleton(
        names=names,
        parents=np.array([-1 if p is None else names.index(p) for _, p, _ in joints]),
        offsets=np.array([j[2] for j in joints], dtype=float),
        channels=[ROOT_CHANNELS] + [ROOT_CHANNELS[3:]] * (len(joints) - 1),
    )


def _walk(skeleton: Skeleton, height: float, swings: dict[str, float], frames: int, fps: float) -> Motion:
    """`frames` of walking along +z at `height`: each joint of `swings` swings about x by that many
    degrees (negative: the opposite phase)."""
    phase = 2 * np.pi * 1.5 * np.arange(frames) / fps
    angles = np.zeros((frames, skeleton.num_joints, 3))
    for name, degrees in swings.items():
        angles[:, skeleton.index(name), 2] = degrees * np.sin(phase)  # X: the third of ZYX
    rotations = np.stack([euler_to_matrix(angles[:, j], "ZYX") for j in range(skeleton.num_joints)], axis=1)
    positions = np.broadcast_to(skeleton.offsets, (frames, skeleton.num_joints, 3)).copy()
    positions[:, 0, 1] = height
    positions[:, 0, 2] = np.arange(frames) * 0.8 / fps * height  # about 0.8 body heights a second
    return Motion(skeleton, rotations, positions, 1.0 / fps)


def quadruped(frames: int = 60, fps: float = 30.0) -> Motion:
    """A dog-like body with Biped names: the spine runs forward along +z, the thighs hang from the pelvis
    and the front legs from the clavicles (Bip01_L_UpperArm ... Bip01_L_Hand); all four feet on the floor."""
    joints = _mirrored([
        ("Bip01", None, (0, 0, 0)),
        ("Bip01_Pelvis", "Bip01", (0, 0, 0)),
        ("Bip01_Spine", "Bip01_Pelvis", (0, 0.2, 3)),
        ("Bip01_Spine1", "Bip01_Spine", (0, 0, 5)),
        ("Bip01_Neck", "Bip01_Spine1", (0, 1.5, 2)),
        ("Bip01_Head", "Bip01_Neck", (0, 1, 3)),
        ("Bip01_L_Clavicle", "Bip01_Spine1", (1.5, -0.2, 0.5)),
        ("Bip01_L_UpperArm", "Bip01_L_Clavicle", (0.5, -1, 0)),
        ("Bip01_L_Forearm", "Bip01_L_UpperArm", (0, -4, 0)),
        ("Bip01_L_Hand", "Bip01_L_Forearm", (0, -4.5, 0)),
        ("Bip01_L_Finger0", "Bip01_L_Hand", (0, -0.5, 1)),
        ("Bip01_L_Thigh", "Bip01_Pelvis", (1.5, -0.5, 0)),
        ("Bip01_L_Calf", "Bip01_L_Thigh", (0, -4.5, 0)),
        ("Bip01_L_Foot", "Bip01_L_Calf", (0, -4.5, 0)),
        ("Bip01_L_Toe0", "Bip01_L_Foot", (0, -0.5, 1)),
        ("Bip01_Tail", "Bip01_Pelvis", (0, 1, -2)),
        ("Bip01_Tail1", "Bip01_Tail", (0, 0, -3)),
    ])  # fmt: skip
    skeleton = _skeleton(joints)
    swings = {"Bip01_L_Thigh": 20, "Bip01_R_Thigh": -20, "Bip01_L_UpperArm": -20, "Bip01_R_UpperArm": 20}
    return _walk(skeleton, 10.0, swings, frames, fps)


def crab(frames: int = 60, fps: float = 30.0) -> Motion:
    """A crab with DEF_BN_ names: eye stalks up and forward, two claws forward and four legs a side
    reaching out and down to the floor; its eye joints come first in the file."""
    body = [
        ("DEF_BN_Root", None, (0, 0, 0)),
        ("DEF_BN_Body", "DEF_BN_Root", (0, 0, 0)),
        ("DEF_BN_Eye_L_01", "DEF_BN_Body", (0.8, 0.5, 1.5)),
        ("DEF_BN_Eye_L_02", "DEF_BN_Eye_L_01", (0, 1, 0.3)),
        ("DEF_BN_Eye_L_03", "DEF_BN_Eye_L_02", (0, 1, 0.3)),
        ("DEF_BN_Claw_L_01", "DEF_BN_Body", (1.5, 0, 2)),
        ("DEF_BN_Claw_L_02", "DEF_BN_Claw_L_01", (0.5, 0, 3)),
        ("DEF_BN_Claw_L_03", "DEF_BN_Claw_L_02", (0, 0, 2.5)),
    ]
    for k, z in enumerate((1.0, 0.0, -1.0, -2.0), 1):
        body += [
            (f"DEF_BN_Leg_L_{k}_01", "DEF_BN_Body", (2, 0.5, z)),
            (f"DEF_BN_Leg_L_{k}_02", f"DEF_BN_Leg_L_{k}_01", (2, -1, 0)),
            (f"DEF_BN_Leg_L_{k}_03", f"DEF_BN_Leg_L_{k}_02", (1, -3, 0)),
        ]
    skeleton = _skeleton(_mirrored(body))
    swings = {f"DEF_BN_Leg_{s}_{k}_01": 15 * (-1) ** k for k in range(1, 5) for s in "LR"}
    return _walk(skeleton, 3.5, swings, frames, fps)
