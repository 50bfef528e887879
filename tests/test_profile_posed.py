"""Profiles from the posed body (issue 32, item 3): up, height and facing measured on the motion, not only
on the rest pose, whatever the rest pose, the root layout or the folder's mix of layouts.

Xia walks (cropped to 2 s) are disguised as other labs write them (tests/disguise.py): a rest pose with
the legs or every bone laid along X (world positions unchanged), the translation split between a new
root and the hips (a root on the floor with the height and bob on the hips, or a smoothed root path with
a small bob on the hips), plus the older disguises (Z up, cm, metres, static and turned roots). The
truth is the original clip's: the head's height above the floor plus the head's End Site, the median
over the clip, Y up, in CMU units.
"""

from __future__ import annotations

import re

import disguise
import numpy as np
import pytest

from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.data.folder import FolderSource
from walkdiff.data.preprocess import detect_profile, preprocess
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import encode
from walkdiff.motion.resample import resample
from walkdiff.retarget.files import convert_file

CLIPS = ("angry_01_000", "proud_02_000", "neutral_07_000")  # walks of upright walkers
FRAMES = 240  # 2 s at 120 fps: a few steps
LEGS = ("LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase")
LEGS += tuple(n.replace("Left", "Right").replace("LHip", "RHip") for n in LEGS)
FEET = ("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase")
Y, Z = (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def _legs_along_x(motion):
    return disguise.axis_rest(motion, joints=LEGS)


def _held_out(motion):
    """The held-out dataset's layout: legs along X in the rest pose, the root on the floor with the
    hips' height and bob below it (Z up and cm follow as disguise steps)."""
    return disguise.split_root(_legs_along_x(motion), "ground")


# name: (change before the disguise steps, disguise steps, the file's up axis, the rest pose is a pose)
LAYOUTS = {
    "native": (None, (), Y, True),
    "z-up, cm": (None, ("z_up", "cm"), Z, True),
    "unreal, static root, metres": (None, ("unreal", "static_root", "metres"), Y, True),
    "mixamo, turned root, cm": (None, ("mixamo", "static_root:X-90", "cm"), Y, True),
    "legs along x": (_legs_along_x, (), Y, False),
    "every bone along x, z-up": (disguise.axis_rest, ("z_up",), Z, False),
    "root on the floor, hips bob": (lambda m: disguise.split_root(m, "ground"), (), Y, True),
    "smoothed root path, hips bob, metres": (lambda m: disguise.split_root(m, "path"), ("metres",), Y, True),
    "held-out: legs along x, root on the floor, z-up, cm": (_held_out, ("z_up", "cm"), Z, False),
}


@pytest.fixture(scope="module")
def natives(xia_dir):
    return {name: read_bvh(xia_dir / f"{name}.bvh").slice(0, FRAMES) for name in CLIPS}


def head_height(motion) -> float:
    """The head's height above the floor plus its End Site, the median over the clip (Y up)."""
    world, sk = motion_world_positions(motion), motion.skeleton
    head = sk.index("Head")
    floor = world[:, [sk.index(n) for n in FEET], 1].min()
    top = np.linalg.norm(sk.end_sites.get(head, np.zeros(3)))
    return float(np.median(world[:, head, 1]) - floor + top)


def disguised(native, layout: str):
    change, steps, _, _ = LAYOUTS[layout]
    return disguise.disguise(change(native) if change else native, steps)


def written(motion, record, path):
    write_bvh(path, motion, precision=disguise.default_precision(record.scale))
    return read_bvh(path)


def test_up_height_and_facing_on_every_clip_of_every_layout(natives, tmp_path):
    worst = {"height %": 0.0, "facing deg": 0.0}
    for layout, (_, _, up, is_pose) in LAYOUTS.items():
        for name, native in natives.items():
            copy, record = disguised(native, layout)
            motion = written(copy, record, tmp_path / "take.bvh")
            profile = SkeletonProfile.detect(motion)
            where = f"{layout}, {name}"
            assert profile.up == up, where
            assert profile.root == record.names["Hips"], where
            # Measured on the posed frames, the body is as tall as its head stands above the floor; the
            # profile takes that height when the rest pose is no pose, else the rest pose's, stood upright
            # (the same for every clip of the skeleton, ~2% below an upright walker's head).
            truth, height = head_height(native), profile.body_height / record.scale
            measured = profile.posed_body_height(motion) / record.scale
            error = abs(measured - truth) / truth
            assert error < 0.03, f"{where}: {measured:.4g} vs {truth:.4g}"
            if is_pose:
                assert height == pytest.approx(SkeletonProfile.detect(native).body_height, rel=1e-5), where
            else:
                assert height == measured, where
            # The root's world rotation is the native hips' in every layout: the same facing axis.
            facing = np.degrees(np.arccos(np.clip(np.dot(profile.forward, Z), -1, 1)))
            assert facing < 3, f"{where}: forward {profile.forward} ({profile.found['forward']})"
            rest = profile.found["rest_pose"]
            assert rest.startswith("a standing pose" if is_pose else "no pose"), f"{where}: {rest}"
            assert any("rest pose is no pose" in n for n in profile.notes) != is_pose, where
            if record.scale != 1.0:
                assert profile.units == ("cm" if record.scale > 1 else "m"), where
            worst = {
                "height %": max(worst["height %"], 100 * error),
                "facing deg": max(worst["facing deg"], facing),
            }
    print(f"worst over {len(LAYOUTS)} layouts x {len(natives)} clips: {worst}")


def test_a_rest_pose_that_is_a_pose_keeps_its_height(natives, xia_dir):
    """A real rest pose gives every clip of the skeleton the same height, a hunched walker's included
    (whose head stays ~13% lower than when stood upright)."""
    hunched = read_bvh(xia_dir / "old_08_003.bvh").slice(0, FRAMES)
    heights = {SkeletonProfile.detect(m).body_height for m in [*natives.values(), hunched]}
    assert len(heights) == 1 and 24.0 < heights.pop() < 24.3  # CMU units, stood upright
    assert head_height(hunched) < 22


def test_inspect_flags_a_rest_pose_that_is_no_pose(natives, tmp_path, capsys):
    native = natives["angry_01_000"]
    for layout, expected in (
        ("native", "rest pose: a standing pose"),
        ("legs along x", "rest pose: no pose"),
    ):
        copy, record = disguised(native, layout)
        path = tmp_path / "take.bvh"
        written(copy, record, path)
        assert main(["inspect", str(path)]) == 0
        out = capsys.readouterr().out
        assert expected in out, out
    assert "its legs do not reach down from the hips" in out
    assert re.search(r"suspicious: \n  - .*the rest pose is no pose", out), out
    assert re.search(r"height: +24\.\d+ units", out)  # not the 39 units its rest pose spans


def test_convert_round_trips_a_translation_shared_with_a_root_on_the_floor(natives, tmp_path):
    layout = "held-out: legs along x, root on the floor, z-up, cm"
    for name in CLIPS[:2]:
        copy, record = disguised(natives[name], layout)
        source, target = tmp_path / f"{name}.bvh", tmp_path / f"{name}_out.bvh"
        original = written(copy, record, source)
        report = convert_file(str(source), str(target))
        assert "Root given the root's path again" in report
        back = read_bvh(target)
        assert back.skeleton.names == original.skeleton.names
        error = np.abs(motion_world_positions(back) - motion_world_positions(original)).max()
        assert error < 1e-4 * 24.1 * record.scale, f"{name}: {error}"
        # The layout too: the root still carries the path on the floor (Z up: its z stays 0).
        np.testing.assert_allclose(back.positions[:, 0, 2], 0.0, atol=1e-6)


def test_convert_refuses_a_round_trip_that_loses_translation(natives, tmp_path, capsys):
    copy, record = disguised(natives["angry_01_000"], "root on the floor, hips bob")
    source, target = tmp_path / "take.bvh", tmp_path / "out.bvh"
    written(copy, record, source)
    settings = tmp_path / "profile.yaml"
    settings.write_text("root: Root\n")  # the root on the floor: the hips' height and bob would be lost
    assert main(["convert", str(source), str(target), "--profile", str(settings)]) == 1
    err = capsys.readouterr().err
    assert (
        "take.bvh" in err and "nothing written" in err and "'Hips'" in err and "below the root 'Root'" in err
    )
    assert not target.exists()


def _folder(tmp_path, name: str, clips: dict) -> FolderSource:
    folder = tmp_path / name
    folder.mkdir()
    for file_name, (motion, record) in clips.items():
        write_bvh(folder / file_name, motion, precision=disguise.default_precision(record.scale))
    return FolderSource(folder)


def _preprocess(source: FolderSource, tmp_path):
    clips = source.list_clips()
    profile = detect_profile(source, clips)
    return preprocess(
        source,
        clips,
        profile,
        fps=30.0,
        mirror=False,
        cache_dir=tmp_path / "cache",
        workers=1,
        progress=False,
    )


def test_a_folder_mixing_root_layouts_is_reconciled(natives, tmp_path):
    """Two clips with the translation on the hips below a static root, one with it on a root on the floor
    and the hips' bob (listed first: the profile comes from it): every clip gives its native features."""
    steps = ("static_root",)
    clips = {
        "a_split.bvh": disguise.disguise(disguise.split_root(natives["angry_01_000"], "ground"), ()),
        "b_hips.bvh": disguise.disguise(natives["proud_02_000"], steps),
        "c_hips.bvh": disguise.disguise(natives["angry_01_000"], steps),
    }
    processed = _preprocess(_folder(tmp_path, "mixed", clips), tmp_path)
    assert processed.profile.root == "Hips" and processed.profile.up == Y
    features = {name.split("/")[-1]: f for name, f in zip(processed.names, processed.features)}
    assert sorted(features) == ["a_split", "b_hips", "c_hips"], sorted(features)
    # The same walk in either layout gives the same features, and those of the native clip.
    np.testing.assert_allclose(features["a_split"], features["c_hips"], atol=1e-4)
    native = natives["angry_01_000"]
    canonical = resample(SkeletonProfile.detect(native).to_canonical(native), 30.0)
    np.testing.assert_allclose(features["c_hips"], encode(canonical, processed.profile), atol=1e-4)


UP_MESSAGE = "the body stands along +z (feet to Head on 100% of the frames), the profile's up is +y"


@pytest.mark.parametrize(
    "odd, steps, message",
    [
        ("z-up", ("static_root", "z_up"), UP_MESSAGE),
        ("cm", ("static_root", "cm"), "other units or another body"),
    ],
)
def test_a_folder_with_a_clip_of_another_layout_refuses_it_by_name(natives, tmp_path, odd, steps, message):
    clips = {
        "a_take.bvh": disguise.disguise(natives["angry_01_000"], ("static_root",)),
        "b_take.bvh": disguise.disguise(natives["proud_02_000"], ("static_root",)),
        f"c_{odd.replace('-', '')}.bvh": disguise.disguise(natives["neutral_07_000"], steps),
    }
    with pytest.raises(WalkdiffError) as caught:
        _preprocess(_folder(tmp_path, odd, clips), tmp_path)
    text = str(caught.value)
    assert "1 clip(s) could not be read" in text and f"c_{odd.replace('-', '')}.bvh" in text, text
    assert "laid out otherwise than the dataset's skeleton profile" in text and message in text, text


def test_a_folder_whose_root_setting_would_drop_the_hips_translation_is_refused(natives, tmp_path):
    clips = {"a_split.bvh": disguise.disguise(disguise.split_root(natives["angry_01_000"], "ground"), ())}
    source = _folder(tmp_path, "rooted", clips)
    source.profile = {"root": "Root"}
    with pytest.raises(
        WalkdiffError, match=r"translation on 'Hips' below the root 'Root' leaves its bone offset"
    ):
        _preprocess(source, tmp_path)
