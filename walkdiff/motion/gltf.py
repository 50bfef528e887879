"""Motion as binary glTF (.glb): the open format of three.js, Blender, Unity, Unreal and web viewers.

A clip becomes one node per joint (the BVH hierarchy, rest translations in metres, Y up as glTF
requires), one animation (a rotation track per joint, a translation track per joint that moves) and a
stick figure skinned to the joints, so that any viewer shows the motion without a character of its own.
pygltflib writes the container; what goes in it is built here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl
import roma
import torch

from walkdiff.common.files import write_atomic
from walkdiff.motion.skeleton import Motion

BONE_WIDTH = 0.03  # metres: the stick figure's bones are square rods this wide


class _Blob:
    """The one binary buffer of a GLB, and the accessors that read from it."""

    def __init__(self, gltf: gl.GLTF2):
        self.gltf, self.data = gltf, bytearray()

    def add(self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        component = gl.UNSIGNED_SHORT if array.dtype == np.uint16 else gl.FLOAT
        array = np.ascontiguousarray(array, dtype=np.uint16 if component == gl.UNSIGNED_SHORT else np.float32)
        while len(self.data) % 4:
            self.data.append(0)
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=len(self.data), byteLength=array.nbytes, target=target)
        )
        self.data.extend(array.tobytes())
        rows = array.reshape(array.shape[0], -1)
        accessor = gl.Accessor(
            bufferView=len(self.gltf.bufferViews) - 1,
            componentType=component,
            count=array.shape[0],
            type=kind,
        )
        if bounds:  # required for positions and animation times
            accessor.min, accessor.max = rows.min(0).tolist(), rows.max(0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1


def _rest_world(motion: Motion, scale: float) -> np.ndarray:
    """(J, 3) joint positions in the rest pose (no rotation), as the skin binds them."""
    skeleton = motion.skeleton
    world = np.zeros((skeleton.num_joints, 3))
    for j, parent in enumerate(skeleton.parents):
        world[j] = motion.positions[0, j] * scale + (world[parent] if parent >= 0 else 0.0)
    return world


def _stick_figure(motion: Motion, rest: np.ndarray, scale: float) -> tuple[np.ndarray, ...]:
    """A square rod per bone (parent -> joint, and joint -> end site), each skinned to its start joint."""
    segments = [(p, rest[p], rest[j]) for j, p in enumerate(motion.skeleton.parents) if p >= 0]
    segments += [(j, rest[j], rest[j] + site * scale) for j, site in motion.skeleton.end_sites.items()]
    positions, joints, indices = [], [], []
    for joint, start, end in segments:
        axis = end - start
        length = np.linalg.norm(axis)
        if length < 1e-6:
            continue
        axis /= length
        side = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[1]) > 0.9 else [0.0, 1.0, 0.0])
        side *= BONE_WIDTH / 2 / np.linalg.norm(side)
        other = np.cross(axis, side)
        ring = np.array([side + other, side - other, -side - other, -side + other])
        base = len(positions) * 8
        positions.append(np.concatenate([start + ring, end + ring]))
        joints.append(np.full(8, joint))
        for k in range(4):  # two triangles per side of the rod
            a, b = k, (k + 1) % 4
            indices += [base + a, base + b, base + 4 + b, base + a, base + 4 + b, base + 4 + a]
    vertices = np.concatenate(positions)
    joint_ids = np.zeros((len(vertices), 4), dtype=np.uint16)
    joint_ids[:, 0] = np.concatenate(joints)
    weights = np.zeros((len(vertices), 4))
    weights[:, 0] = 1.0
    return vertices, joint_ids, weights, np.asarray(indices, dtype=np.uint16)


def _quaternions(rotations: np.ndarray) -> np.ndarray:
    """(F, J, 3, 3) -> (F, J, 4) xyzw, signs chosen so that consecutive frames interpolate the short way."""
    q = roma.rotmat_to_unitquat(torch.from_numpy(rotations)).numpy()
    for f in range(1, len(q)):
        flip = (q[f] * q[f - 1]).sum(-1) < 0
        q[f, flip] *= -1
    return q


def gltf_document(motion: Motion, metres_per_unit: float, name: str = "walkdiff") -> gl.GLTF2:
    """A Y-up motion (canonical, as SkeletonProfile.to_canonical gives it) as a glTF document in metres."""
    skeleton, scale, frames = motion.skeleton, metres_per_unit, motion.num_frames
    gltf = gl.GLTF2(asset=gl.Asset(generator="walkdiff"), scene=0)
    blob = _Blob(gltf)
    moving = np.ptp(motion.positions, axis=0).max(-1) > 1e-9  # joints whose translation is animated
    quaternions = _quaternions(motion.rotations)
    for j, joint in enumerate(skeleton.names):
        children = [int(c) for c in np.flatnonzero(skeleton.parents == j)]
        gltf.nodes.append(
            gl.Node(
                name=joint,
                children=children or None,
                translation=(motion.positions[0, j] * scale).tolist(),
                rotation=quaternions[0, j].tolist(),
            )
        )

    rest = _rest_world(motion, scale)
    vertices, joint_ids, weights, indices = _stick_figure(motion, rest, scale)
    inverse_bind = np.tile(np.eye(4), (skeleton.num_joints, 1, 1))
    inverse_bind[:, :3, 3] = -rest
    # glTF matrices are column-major: the transpose's rows are the columns.
    gltf.skins.append(
        gl.Skin(
            joints=list(range(skeleton.num_joints)),
            skeleton=0,
            inverseBindMatrices=blob.add(inverse_bind.transpose(0, 2, 1).reshape(-1, 16), gl.MAT4),
        )
    )
    primitive = gl.Primitive(
        attributes=gl.Attributes(
            POSITION=blob.add(vertices, gl.VEC3, gl.ARRAY_BUFFER, bounds=True),
            JOINTS_0=blob.add(joint_ids, gl.VEC4, gl.ARRAY_BUFFER),
            WEIGHTS_0=blob.add(weights, gl.VEC4, gl.ARRAY_BUFFER),
        ),
        indices=blob.add(indices, gl.SCALAR, gl.ELEMENT_ARRAY_BUFFER),
    )
    gltf.meshes.append(gl.Mesh(name=f"{name} stick figure", primitives=[primitive]))
    gltf.nodes.append(gl.Node(name=f"{name} stick figure", mesh=0, skin=0))

    times = blob.add(np.arange(frames) * motion.frame_time, gl.SCALAR, bounds=True)
    samplers, channels = [], []
    for j in range(skeleton.num_joints):
        tracks = [("rotation", quaternions[:, j], gl.VEC4)]
        if moving[j]:
            tracks.append(("translation", motion.positions[:, j] * scale, gl.VEC3))
        for path, values, kind in tracks:
            samplers.append(
                gl.AnimationSampler(input=times, output=blob.add(values, kind), interpolation="LINEAR")
            )
            channels.append(
                gl.AnimationChannel(
                    sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=j, path=path)
                )
            )
    gltf.animations.append(gl.Animation(name=name, samplers=samplers, channels=channels))
    gltf.scenes.append(gl.Scene(nodes=[0, skeleton.num_joints]))
    gltf.buffers.append(gl.Buffer(byteLength=len(blob.data)))
    gltf.set_binary_blob(bytes(blob.data))
    return gltf


def write_glb(path: str | Path, motion: Motion, metres_per_unit: float) -> Path:
    """Write a Y-up motion as a .glb file (atomically)."""
    path = Path(path)
    document = gltf_document(motion, metres_per_unit, name=path.stem)
    return write_atomic(path, lambda f: f.write(b"".join(document.save_to_bytes())))
