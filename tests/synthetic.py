"""Synthetic motion made by the tests themselves (no real capture is ever committed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.profile import ContactSpec
from walkdiff.motion.rotations import euler_to_matrix
from walkdiff.motion.skeleton import Motion, Skeleton

# A small CMU-like hierarchy with the joint names Xia's contact and mirror settings use.
JOINTS = [
    ("Hips", -1, (0, 0, 0)),
    ("LHipJoint", 0, (0, 0, 0)),
    ("LeftUpLeg", 1, (1.4, -1.8, 0.8)),
    ("LeftLeg", 2, (0, -6.9, 0)),
    ("LeftFoot", 3, (0, -7.2, 0)),
    ("LeftToeBase", 4, (0, -0.4, 2.3)),
    ("RHipJoint", 0, (0, 0, 0)),
    ("RightUpLeg", 6, (-1.4, -1.8, 0.8)),
    ("RightLeg", 7, (0, -6.9, 0)),
    ("RightFoot", 8, (0, -7.2, 0)),
    ("RightToeBase", 9, (0, -0.4, 2.3)),
    ("Spine", 0, (0, 2.0, 0)),
    ("Head", 11, (0, 6.0, 0)),
]


def skeleton() -> Skeleton:
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")]
    channels += [("Zrotation", "Yrotation", "Xrotation")] * (len(JOINTS) - 1)
    return Skeleton(
        names=[j[0] for j in JOINTS],
        parents=np.array([j[1] for j in JOINTS]),
        offsets=np.array([j[2] for j in JOINTS], dtype=float),
        channels=channels,
        end_sites={5: np.array([0, 0, 1.0]), 10: np.array([0, 0, 1.0]), 12: np.array([0, 1.0, 0])},
    )


def walking(frames: int = 240, fps: float = 120.0, seed: int = 0, turn: float = 0.3) -> Motion:
    """A swinging-legs walk along a gently turning path (smooth, so contacts and FK are well behaved)."""
    rng = np.random.default_rng(seed)
    sk = skeleton()
    time = np.arange(frames) / fps
    phase = 2 * np.pi * 1.0 * time + rng.uniform(0, 2 * np.pi)
    angles = np.zeros((frames, sk.num_joints, 3))
    angles[:, 2, 2] = 25 * np.sin(phase)  # left hip swings about X (third channel of ZYX)
    angles[:, 7, 2] = -25 * np.sin(phase)
    angles[:, 3, 2] = 20 * np.clip(np.sin(phase + 1), 0, None)
    angles[:, 8, 2] = 20 * np.clip(-np.sin(phase + 1), 0, None)
    angles[:, 11, 0] = 3 * np.sin(2 * phase) + rng.normal(0, 0.5)
    heading = turn * time + rng.uniform(-1, 1)
    angles[:, 0, 1] = np.degrees(heading)
    rotations = np.stack([euler_to_matrix(angles[:, j], "ZYX") for j in range(sk.num_joints)], axis=1)
    positions = np.broadcast_to(sk.offsets, (frames, sk.num_joints, 3)).copy()
    speed = 12.0  # units per second
    positions[:, 0, 0] = np.cumsum(np.sin(heading)) * speed / fps
    positions[:, 0, 2] = np.cumsum(np.cos(heading)) * speed / fps
    positions[:, 0, 1] = 16.0 + 0.3 * np.sin(2 * phase)
    return Motion(sk, rotations, positions, 1.0 / fps)


def xia_like_folder(root: Path, styles=("angry", "old"), walk_clips: int = 6, frames: int = 240) -> Path:
    """`root/xia/STYLE_CC_NNN.bvh`: walk clips plus one run clip per style, in the Xia naming scheme."""
    folder = root / "xia"
    folder.mkdir(parents=True, exist_ok=True)
    seed = 0
    for style in styles:
        for i in range(walk_clips):
            seed += 1
            write_bvh(folder / f"{style}_{1 + i % 12:02d}_{i // 12:03d}.bvh", walking(frames, seed=seed))
        seed += 1
        write_bvh(folder / f"{style}_13_000.bvh", walking(frames, seed=seed, turn=0.0))
    return folder


def xia_profile(motion: Motion):
    """The skeleton profile walkdiff finds for a Xia clip (or the synthetic CMU-like one above)."""
    from walkdiff.data.xia import PROFILE
    from walkdiff.motion.profile import SkeletonProfile

    return SkeletonProfile.detect(motion, PROFILE)


# Xia's contact joints with the thresholds its profile gives (0.2 and 0.02 of its 24.1-unit height).
XIA_CONTACTS = ContactSpec("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase", 4.83, 0.483)


def quiet_trainer(**overrides):
    """A CPU Trainer for a few test steps: no logger, checkpoints, progress bar, summary or sanity check."""
    import lightning as L

    defaults = dict(
        accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, limit_val_batches=1, num_sanity_val_steps=0,
    )  # fmt: skip
    return L.Trainer(**(defaults | overrides))
