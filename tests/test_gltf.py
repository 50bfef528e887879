"""`walkdiff convert X.bvh Y.glb`: read back, the glTF animation puts every joint where forward
kinematics of the clip does, Y up and in metres, whatever the file's axes, units and layout."""

from __future__ import annotations

import numpy as np
import pygltflib as gl
import pytest
import roma
import torch
from disguise import disguise

from walkdiff.cli.main import main
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile

COMPONENTS = {gl.FLOAT: np.float32, gl.UNSIGNED_SHORT: np.uint16}
WIDTH = {gl.SCALAR: 1, gl.VEC3: 3, gl.VEC4: 4, gl.MAT4: 16}


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


def _accessor(document: gl.GLTF2, index: int) -> np.ndarray:
    accessor = document.accessors[index]
    view = document.bufferViews[accessor.bufferView]
    blob = document.binary_blob()
    data = np.frombuffer(
        blob,
        COMPONENTS[accessor.componentType],
        offset=view.byteOffset,
        count=accessor.count * WIDTH[accessor.type],
    )
    return data.reshape(accessor.count, -1)


def _world_positions(document: gl.GLTF2, frame: int) -> dict[str, np.ndarray]:
    """Every joint node's world position at `frame`, from the animation tracks and the node tree."""
    local = {i: (np.array(n.translation), np.array(n.rotation)) for i, n in enumerate(document.nodes)}
    animation = document.animations[0]
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        value = _accessor(document, sampler.output)[frame].astype(np.float64)
        translation, rotation = local[channel.target.node]
        local[channel.target.node] = (
            (value, rotation) if channel.target.path == "translation" else (translation, value)
        )
    world = {}

    def visit(node: int, rotation: np.ndarray, position: np.ndarray) -> None:
        translation, quaternion = local[node]
        position = position + rotation @ translation
        rotation = rotation @ roma.unitquat_to_rotmat(torch.from_numpy(quaternion)).numpy()
        world[document.nodes[node].name] = position
        for child in document.nodes[node].children or []:
            visit(child, rotation, position)

    visit(document.scenes[0].nodes[0], np.eye(3), np.zeros(3))
    return world


@pytest.mark.parametrize("steps", [(), ("z_up", "metres", "static_root", "order:XYZ")])
def test_glb_joints_follow_forward_kinematics_in_metres_y_up(xia_dir, tmp_path, capsys, steps):
    motion = read_bvh(xia_dir / "old_13_000.bvh").slice(0, 120)
    if steps:
        motion, _ = disguise(motion, steps)
    source = tmp_path / "clip.bvh"
    write_bvh(source, motion)
    target = tmp_path / "clip.glb"
    assert main(["convert", str(source), str(target)]) == 0
    assert "glTF (Y up, metres)" in capsys.readouterr().out

    document = gl.GLTF2().load(str(target))
    profile = SkeletonProfile.detect(read_bvh(source))
    canonical = profile.to_canonical(read_bvh(source))
    expected = motion_world_positions(canonical) * profile.metres_per_unit
    times = _accessor(document, document.animations[0].samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(canonical.num_frames) * canonical.frame_time, atol=1e-5)
    for frame in (0, 57, canonical.num_frames - 1):
        world = _world_positions(document, frame)
        got = np.stack([world[name] for name in canonical.skeleton.names])
        np.testing.assert_allclose(got, expected[frame], atol=1e-4)  # metres
    # Y up, in metres: the head is over a metre above the feet, whatever the file's axes and units.
    names = canonical.skeleton.names
    head, foot = (next(i for i, n in enumerate(names) if key in n.lower()) for key in ("head", "foot"))
    assert 1.0 < expected[0, head, 1] - expected[0, foot, 1] < 2.0

    # The stick figure is skinned to the skeleton's joints and binds at the rest pose.
    skin = document.skins[0]
    assert len(skin.joints) == canonical.skeleton.num_joints
    joints = _accessor(document, document.meshes[0].primitives[0].attributes.JOINTS_0)
    assert joints.max() < len(skin.joints) and len(np.unique(joints[:, 0])) > 10


def test_convert_refuses_formats_it_does_not_write(xia_dir, tmp_path, capsys):
    assert main(["convert", str(xia_dir / "old_13_000.bvh"), str(tmp_path / "clip.fbx")]) == 1
    assert "expected an output ending in .bvh or .glb" in capsys.readouterr().err
    assert not (tmp_path / "clip.fbx").exists()
