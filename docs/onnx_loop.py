"""A game loop against an exported walkdiff frame, with numpy and ONNX Runtime alone: what an engine does
each frame, written from the JSON contract only (docs/game-engines.md). It imports nothing of walkdiff.

    walkdiff export --format onnx --ckpt checkpoints/walk_xia/last.ckpt --out engine/
    python docs/onnx_loop.py engine/walker.json --frames 300 --out walked.npz

A walker walks straight on along +Z at its style's own speed; a gesture model (gesture.json) gestures to
log-mel frames given as a .npy file (--audio, (frames, n_mels), as the contract's audio section makes
them). --noise: the noise of every frame from a .npy file (frames, slots, 1, D) instead of drawn here.
The .npz holds each frame's pose features (pose), the joints' local rotation matrices (rotations) and
world positions (positions) on the contract's skeleton, in its units.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import onnxruntime as ort


def sixd_to_matrix(v: np.ndarray) -> np.ndarray:
    """(J, 6) -> (J, 3, 3): Gram-Schmidt of the two columns a1, a2; the third is their cross product."""
    a1, a2 = v[:, :3], v[:, 3:]
    b1 = a1 / np.linalg.norm(a1, axis=-1, keepdims=True)
    b2 = a2 - (b1 * a2).sum(-1, keepdims=True) * b1
    b2 = b2 / np.linalg.norm(b2, axis=-1, keepdims=True)
    return np.stack([b1, b2, np.cross(b1, b2)], axis=-1)


def expmap_to_matrix(v: np.ndarray) -> np.ndarray:
    """(J, 3) rotation vectors -> (J, 3, 3) by Rodrigues' formula."""
    out = np.repeat(np.eye(3)[None], len(v), axis=0)
    for j, r in enumerate(v):
        angle = np.linalg.norm(r)
        if angle < 1e-12:
            continue
        x, y, z = r / angle
        k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        out[j] = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    return out


def yaw(h: float) -> np.ndarray:
    return np.array([[math.cos(h), 0, math.sin(h)], [0, 1, 0], [-math.sin(h), 0, math.cos(h)]])


def forward_kinematics(rotations: np.ndarray, root: np.ndarray, skeleton: dict) -> np.ndarray:
    """World positions (J, 3) from local rotations (J, 3, 3), the root's position and the offsets."""
    offsets, parents = np.asarray(skeleton["offsets"]), skeleton["parents"]
    world, positions = np.empty_like(rotations), np.empty((len(parents), 3))
    for j, p in enumerate(parents):  # parents come before their children
        if p < 0:
            world[j], positions[j] = rotations[j], root
        else:
            world[j] = world[p] @ rotations[j]
            positions[j] = positions[p] + world[p] @ offsets[j]
    return positions


class Frame:
    """The exported graph and the state it carries from frame to frame, for one character."""

    def __init__(self, terms: dict, folder: Path):
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        self.session = ort.InferenceSession(
            str(folder / terms["onnx"]), options, providers=["CPUExecutionProvider"]
        )
        shapes = {i["name"]: i["shape"] for i in terms["inputs"]}
        self.state = {
            n: np.zeros([1 if d == "batch" else d for d in shapes[n]], np.float32)
            for n in ("previous", "h", "c")
        }

    def run(self, feeds: dict, noise: np.ndarray) -> np.ndarray:
        pose, self.state["previous"], self.state["h"], self.state["c"] = self.session.run(
            ["pose", "previous_out", "h_out", "c_out"], feeds | self.state | {"noise": noise}
        )
        return pose[0]


def walk(terms: dict, frame: Frame, frames: int, noises, style: str | None):
    control = terms["control"]
    styles = list(control["style_speed"])
    style = style or styles[0]
    weights = np.array([[float(s == style) for s in styles]], np.float32)
    speed = control["style_speed"][style]  # units per second
    times = np.asarray(control["ahead_frames"]) / terms["fps"]
    layout = terms["features"]["layout"]
    rot = slice(*layout["rotations"])
    x = z = heading = 0.0
    target = 0.0  # walk towards +Z
    out = []
    for t in range(frames):
        delta = (target - heading + math.pi) % (2 * math.pi) - math.pi
        delta = math.pi if delta == -math.pi else min(max(delta, -math.pi / 2), math.pi / 2)
        points = np.stack([speed * times * math.sin(delta), speed * times * math.cos(delta)], -1)
        pose = frame.run({"control": points.reshape(1, -1).astype(np.float32), "style": weights}, noises(t))
        raw = pose.astype(np.float64)
        rotations = sixd_to_matrix(raw[rot].reshape(-1, 6))
        rotations[0] = yaw(heading) @ rotations[0]
        positions = forward_kinematics(rotations, np.array([x, raw[2], z]), terms["skeleton"])
        out.append((pose, rotations, positions))
        vx, vz = raw[0], raw[1]
        x, z = (
            x + vx * math.cos(heading) + vz * math.sin(heading),
            z - vx * math.sin(heading) + vz * math.cos(heading),
        )
        heading += raw[3]
    return out


def gesture(terms: dict, frame: Frame, audio: np.ndarray, noises):
    past, ahead = terms["audio"]["past"], terms["audio"]["lookahead"]
    modelled = terms["skeleton_joints_modelled"]
    per_joint = 6 if terms["features"]["rotation"] == "6d" else 3
    neutral = np.asarray(terms["neutral_pose"]["rotations"])
    root = np.asarray(terms["neutral_pose"]["root"])
    out = []
    for t in range(len(audio)):
        window = audio[np.clip(np.arange(t - past, t + ahead + 1), 0, len(audio) - 1)]
        pose = frame.run({"audio": window[None].astype(np.float32)}, noises(t))
        values = pose.astype(np.float64).reshape(-1, per_joint)
        rotations = neutral.copy()
        rotations[modelled] = sixd_to_matrix(values) if per_joint == 6 else expmap_to_matrix(values)
        out.append((pose, rotations, forward_kinematics(rotations, root, terms["skeleton"])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("contract", help="the .json beside the exported .onnx")
    parser.add_argument("--frames", type=int, default=300, help="walker: frames to walk")
    parser.add_argument("--audio", help="gesture model: log-mel frames (frames, n_mels) as .npy")
    parser.add_argument("--style", help="walker: the style to walk in (default: the first)")
    parser.add_argument("--noise", help="noise of every frame, (frames, slots, 1, D) .npy (default: drawn)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, help=".npz of poses, rotations and positions")
    args = parser.parse_args()
    path = Path(args.contract)
    terms = json.loads(path.read_text())
    frame = Frame(terms, path.parent)
    shape = [1 if d == "batch" else d for d in terms["noise"]["shape"]]
    if args.noise:
        given = np.load(args.noise)
        noises = lambda t: given[t]  # noqa: E731
    else:
        rng = np.random.default_rng(args.seed)
        noises = lambda t: rng.standard_normal(shape).astype(np.float32)  # noqa: E731
    if terms["kind"] == "walker":
        made = walk(terms, frame, args.frames, noises, args.style)
    else:
        made = gesture(terms, frame, np.load(args.audio), noises)
    pose, rotations, positions = (np.stack(v) for v in zip(*made))
    np.savez(args.out, pose=pose, rotations=rotations, positions=positions)
    print(f"{len(pose)} frames: {args.out}")


if __name__ == "__main__":
    main()
