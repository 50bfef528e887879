"""Know a body before retargeting it (issue 46): rigs with human names that do not stand like a biped are
refused from their posed frames, with what was measured; humanoids never are; leg finding never takes
chains that do not end on the floor (a crab's eye stalks were called its legs)."""

from __future__ import annotations

import creatures
import disguise
import pytest

from walkdiff.bench.rig_variants import legs, reposed
from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.humanoid import humanoid_map
from walkdiff.motion.posed_frames import world_transforms
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.retarget.body_check import body_problems
from walkdiff.retarget.retargeter import Retargeter
from walkdiff.retarget.rigs import SPECS, rig


@pytest.fixture(scope="module")
def xia(xia_dir):
    return {
        name: read_bvh(xia_dir / f"{name}.bvh") for name in ("strutting_08_002", "old_13_000", "angry_22_000")
    }


@pytest.fixture(scope="module")
def zeggs(zeggs_dir):
    return read_bvh(zeggs_dir / "067_Speech_2_x_1_0.bvh").slice(0, 600)


def test_a_quadruped_with_biped_names_is_refused_naming_what_was_measured(xia):
    """It retargeted onto mixamo with rc 0 and a full humanoid map."""
    dog = creatures.quadruped()
    assert humanoid_map(dog).left_upper_arm == "Bip01_L_UpperArm"  # the names alone make it a human
    with pytest.raises(WalkdiffError) as refused:
        Retargeter(dog, rig("mixamo"))
    message = str(refused.value)
    assert message.startswith("retarget: the source (the clip's skeleton) does not stand like a biped: ")
    assert "its spine (Bip01_Pelvis to Bip01_Neck) is 80 deg from up" in message
    assert "its hands (Bip01_L_Hand, Bip01_R_Hand) are 8% of a leg above the floor" in message
    assert message.endswith("`walkdiff retarget --force` (force=True) retargets it anyway")
    assert "\n" not in message
    # As the target, too (its first frame), and --force keeps the old behaviour.
    with pytest.raises(WalkdiffError, match="the target rig does not stand like a biped: its spine"):
        Retargeter(xia["strutting_08_002"], dog)
    assert Retargeter(dog, rig("mixamo"), force=True)(dog).motion.num_frames == dog.num_frames


def test_a_crab_is_refused_and_its_eyes_are_never_a_leg():
    """The message called its eye joints a leg ('DEF_BN_Eye_L_03 -7% of the leg below them'): legs
    found from the hierarchy end on the floor, where most joints touch it."""
    crab = creatures.crab()
    feet = SkeletonProfile.detect(crab).feet
    assert all("Leg" in joint for joint in feet.values()), feet
    hmap = humanoid_map(crab)
    assert "Leg" in hmap.left_thigh and "Leg" in hmap.right_foot
    with pytest.raises(WalkdiffError, match=r"does not stand like a biped: its spine \(DEF_BN_Body to") as no:
        Retargeter(crab, rig("mixamo"))
    assert "Eye" not in str(no.value)


def test_the_command_refuses_in_one_line_and_force_retargets(tmp_path, capsys):
    source = tmp_path / "dog.bvh"
    write_bvh(source, creatures.quadruped())
    out = tmp_path / "dog_on_mixamo.bvh"
    assert main(["retarget", str(source), "--to", "mixamo", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("walkdiff: error: retarget: the source") and "80 deg" in err[0]
    assert not out.exists()
    assert main(["retarget", str(source), "--to", "mixamo", "--out", str(out), "--force"]) == 0
    assert read_bvh(out).num_frames == 60


def problems(motion) -> list[str]:
    return body_problems(world_transforms(motion)[0], motion.skeleton, humanoid_map(motion))


def test_no_humanoid_is_refused(xia, zeggs):
    """Xia (walking, running, kicking), ZEGGS, the built-in rigs' rest poses, the disguised copies the
    tests make (other names, units, axes, rest poses, frame rates, a static root, proportions)."""
    clips = {**xia, "zeggs": zeggs}
    walk = xia["strutting_08_002"]
    for convention in disguise.CONVENTIONS:
        clips[f"xia as {convention}"] = disguise.rename(walk, convention)[0]
    clips["xia disguised"] = disguise.disguise(walk)[0]
    clips["xia with a static root"] = disguise.static_root(walk)
    clips["xia split root"] = disguise.split_root(walk)
    clips["xia axis rest"] = disguise.axis_rest(walk)
    clips["xia re-posed"] = reposed(walk)
    clips["xia long legs"] = legs(walk.skeleton, 1.25)
    clips["zeggs disguised"] = disguise.disguise(zeggs.slice(0, 120), ("mixamo", "order:XYZ", "z_up"))[0]
    for name in SPECS:
        clips[f"built-in {name}"] = rig(name)
    refused = {}
    for name, clip in clips.items():
        clip = clip if hasattr(clip, "rotations") else _rest_clip(clip)
        found = problems(clip)
        if found:
            refused[name] = found
    assert refused == {}
    for name in SPECS:  # both ways through the retargeter, unforced
        Retargeter(walk, rig(name))
        Retargeter(zeggs, rig(name))


def _rest_clip(skeleton):
    from walkdiff.retarget.retargeter import _target_motion

    return _target_motion(skeleton, None)[0]


def test_no_clip_of_xia_or_zeggs_is_refused(xia_dir, zeggs_dir):
    """Every clip: walking, running, jumping (an old man's crouched jumps lean 62 deg on the frames where
    the pelvis is back over the feet: one up for the clip), punching, kicking, gesturing."""
    files = sorted(xia_dir.glob("*.bvh")) + sorted(zeggs_dir.glob("*.bvh"))
    refused = {}
    for path in files:
        clip = read_bvh(path)
        found = problems(_every(clip, max(1, clip.num_frames // 300)))
        if found:
            refused[path.name] = found
    assert len(files) == 573 and refused == {}


def _every(clip, step: int):
    from walkdiff.motion.skeleton import Motion

    return Motion(clip.skeleton, clip.rotations[::step], clip.positions[::step], clip.frame_time)
