"""Stick-figure GIF/PNG previews: file format, timing, framing, colours, atomic writes and bad input."""

from __future__ import annotations

import time

import numpy as np
import pytest
from PIL import Image, ImageSequence

from walkdiff.common.errors import WalkdiffError
from walkdiff.preview import render, scene
from walkdiff.preview.render import render_gif, render_png

NAMES = ["Hips", "Spine", "Head", "LeftUpLeg", "LeftFoot", "RightUpLeg", "RightFoot", "LeftHand", "RightHand"]
PARENTS = np.array([-1, 0, 1, 0, 3, 0, 5, 1, 1])


def walker(frames: int = 120, fps: float = 60, speed: float = 1.2, scale: float = 1.0) -> np.ndarray:
    """A figure walking along +X: legs and arms swing at 1 Hz, root bobs a little. (F, 9, 3), Y up."""
    t = np.arange(frames)[:, None] / fps
    swing = 0.3 * np.sin(2 * np.pi * t)
    hips = np.hstack([speed * t, 0.95 + 0.02 * np.cos(4 * np.pi * t), 0 * t])
    spine = hips + [0.0, 0.5, 0.0]
    joints = [
        hips,
        spine,
        spine + [0.0, 0.25, 0.0],
        hips + [0.0, 0.0, 0.1],
        hips + np.hstack([swing, -0.9 + 0 * t, 0.1 + 0 * t]),
        hips + [0.0, 0.0, -0.1],
        hips + np.hstack([-swing, -0.9 + 0 * t, -0.1 + 0 * t]),
        spine + np.hstack([-swing, -0.6 + 0 * t, 0.2 + 0 * t]),
        spine + np.hstack([swing, -0.6 + 0 * t, -0.2 + 0 * t]),
    ]
    return np.stack(joints, axis=1) * scale


def gif_frames(path) -> tuple[list[np.ndarray], list[int]]:
    with Image.open(path) as image:
        assert image.format == "GIF"
        frames = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(image)]
        image.seek(0)
        delays = []
        for k in range(image.n_frames):
            image.seek(k)
            delays.append(image.info["duration"])
    return frames, delays


def mask(frame: np.ndarray, color: tuple[int, int, int]) -> np.ndarray:
    return (frame == np.array(color, dtype=np.uint8)).all(axis=-1)


def extent(m: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(m)
    return rows.min(), rows.max(), cols.min(), cols.max()


@pytest.mark.parametrize(("fps", "max_fps", "step"), [(120, 30, 4), (25, 30, 1), (60, 24, 3)])
def test_gif_frames_timing_and_size(tmp_path, fps, max_fps, step):
    num = 101
    path = render_gif(tmp_path / "walk.gif", [walker(num, fps), walker(num // 2, fps)], PARENTS, fps,
                      max_fps=max_fps, size=(160, 120))  # fmt: skip
    frames, delays = gif_frames(path)
    assert len(frames) == len(range(0, num, step))
    assert frames[0].shape == (120, 2 * 160, 3)
    # GIF delays are whole centiseconds: each is within 10 ms of the true frame time, and they add up.
    frame_ms = 1000 * step / fps
    assert all(d % 10 == 0 and abs(d - frame_ms) < 10 for d in delays)
    assert abs(sum(delays) - len(frames) * frame_ms) <= 5


def test_gif_different_poses_give_different_frames(tmp_path):
    moving = render_gif(tmp_path / "moving.gif", walker(60, 30), PARENTS, 30, size=(120, 120))
    still = render_gif(tmp_path / "still.gif", np.repeat(walker(1), 60, axis=0), PARENTS, 30, size=(120, 120))
    moving_frames, _ = gif_frames(moving)
    still_frames, _ = gif_frames(still)
    figure = slice(0, 100)  # above the clock in the bottom-left corner
    assert not np.array_equal(moving_frames[0][figure], moving_frames[7][figure])
    assert np.array_equal(still_frames[0][figure], still_frames[7][figure])
    assert not np.array_equal(still_frames[0], still_frames[7])  # the clock moves on


def test_trail_is_drawn_behind_the_walker(tmp_path):
    body = (200, 0, 0)
    clip = walker(90, 30)  # walks along +X, which the camera shows going right
    with_trail, _ = gif_frames(render_gif(tmp_path / "a.gif", clip, PARENTS, 30, colors=[body]))
    without, _ = gif_frames(render_gif(tmp_path / "b.gif", clip, PARENTS, 30, colors=[body], trail=False))
    newest = scene._mix(body, scene.TRAIL_SHADES / (scene.TRAIL_SHADES + 1))  # the trail's strongest shade
    trail = mask(with_trail[-1], newest)
    assert trail.sum() > 20
    assert np.nonzero(trail)[1].mean() < 160 - 20  # left of the root, which stays in the middle
    assert mask(without[-1], newest).sum() == 0
    assert mask(with_trail[0], newest).sum() == 0  # nothing walked yet


def test_left_and_right_limbs_are_coloured_by_name(tmp_path):
    named, _ = gif_frames(render_gif(tmp_path / "n.gif", walker(30), PARENTS, 30, names=NAMES))
    plain, _ = gif_frames(render_gif(tmp_path / "p.gif", walker(30), PARENTS, 30))
    for color in (scene.LEFT, scene.RIGHT):
        assert mask(named[0], color).sum() > 50
        assert mask(plain[0], color).sum() == 0


def test_joint_sides_from_the_mirror_pairs_of_the_names():
    names = ["LeftUpLeg", "RightUpLeg", "LHipJoint", "RHipJoint", "l_hip", "r_hip", "hip.L", "hip.R",
             "LThumb", "RThumb", "RightForeArm", "LeftForeArm", "hip_r", "hip_l", "Bip01 L Foot",
             "Bip01 R Foot", "LowerBack", "Root", "Hips", "Head", "LeftEye"]  # fmt: skip
    sides = "LRLRLRLRLRRLRLLR" + "....."  # LeftEye has no partner: the centre colour
    expected = [{"L": scene.LEFT, "R": scene.RIGHT, ".": None}[s] for s in sides]
    assert scene.limb_sides(names) == expected


def test_upright_framed_and_equal_scale(tmp_path):
    big, small = (200, 0, 0), (0, 0, 200)
    clips = [walker(120, 30, speed=3.0), walker(120, 30, speed=3.0, scale=0.5)]
    frames, _ = gif_frames(
        render_gif(tmp_path / "s.gif", clips, PARENTS, 30, colors=[big, small], size=(150, 200))
    )
    for frame in (frames[0], frames[-1]):  # 12 m walked: the camera follows the root
        top, bottom, left, right = extent(mask(frame[:, :150], big))
        assert 0 < top and bottom < 199 and 0 < left and right < 149
        assert abs((left + right) / 2 - 75) < 30
        small_top, small_bottom, _, _ = extent(mask(frame[:, 150:], small))
        # One scale for all clips: the half-size figure is half as tall on screen.
        assert (small_bottom - small_top) / (bottom - top) == pytest.approx(0.5, abs=0.08)
    named = gif_frames(render_gif(tmp_path / "u.gif", clips[0], PARENTS, 30, names=NAMES))[0][0]
    # Upright: the head (centre colour) is above both feet.
    head_top = extent(mask(named, scene.BODY))[0]
    assert head_top < extent(mask(named, scene.LEFT))[1] - 100
    assert head_top < extent(mask(named, scene.RIGHT))[1] - 100


def test_png_filmstrip(tmp_path):
    path = render_png(tmp_path / "strip.png", [walker(90), walker(60)], PARENTS, frames=4, size=(100, 120),
                      titles=["a", "b"], names=NAMES)  # fmt: skip
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.size == (4 * 100, 2 * 120)
        strip = np.asarray(image.convert("RGB"))
    cells = [strip[:120, k * 100 : (k + 1) * 100] for k in range(4)]
    assert all(mask(cell, scene.LEFT).any() for cell in cells)
    assert not np.array_equal(cells[0], cells[1])


def test_atomic_write_leaves_only_the_result(tmp_path, monkeypatch):
    target = tmp_path / "out" / "walk.gif"
    render_gif(target, walker(20), PARENTS, 30)
    render_png(tmp_path / "out" / "walk.png", walker(20), PARENTS)
    assert sorted(p.name for p in target.parent.iterdir()) == ["walk.gif", "walk.png"]
    before = target.read_bytes()

    def broken_save(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(WalkdiffError, match=r"walk.gif: cannot write \(disk full\)"):  # the file named
        render_gif(target, walker(40), PARENTS, 30)
    assert sorted(p.name for p in target.parent.iterdir()) == ["walk.gif", "walk.png"]
    assert target.read_bytes() == before


@pytest.mark.parametrize(
    ("positions", "match"),
    [
        (np.zeros((10, 9)), r"\(frames, 9, 3\)"),
        (np.zeros((10, 8, 3)), r"\(frames, 9, 3\)"),
        (np.zeros((10, 9, 2)), r"\(frames, 9, 3\)"),
        (np.zeros((0, 9, 3)), r"\(frames, 9, 3\)"),
        ([walker(10), np.zeros((10, 9))], r"positions\[1\].*\(frames, 9, 3\)"),
        (np.full((10, 9, 3), np.nan), "NaN"),
        ([], "no clip"),
    ],
)
def test_bad_positions_raise(tmp_path, positions, match):
    with pytest.raises(WalkdiffError, match=match):
        render_gif(tmp_path / "x.gif", positions, PARENTS, 30)
    with pytest.raises(WalkdiffError, match=match):
        render_png(tmp_path / "x.png", positions, PARENTS)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"parents": [0, 0, 1, 0, 3, 0, 5, 1, 1]}, "-1 for the root"),
        ({"parents": [-1, 0, 1, 0, 3, 0, 5, 1, 12]}, "bad at"),
        ({"parents": np.zeros((3, 3), dtype=int)}, r"\(J,\)"),
        ({"fps": 0}, "fps"),
        ({"max_fps": 100}, "max_fps"),
        ({"titles": ["a", "b"]}, "titles must have 1"),
        ({"names": NAMES[:3]}, "names must have 9"),
        ({"colors": [(1, 2)]}, "colors"),
        ({"size": (10, 200)}, "size"),
    ],
)
def test_bad_arguments_raise(tmp_path, kwargs, match):
    args = {"parents": PARENTS, "fps": 30} | kwargs
    with pytest.raises(WalkdiffError, match=match):
        render_gif(tmp_path / "x.gif", walker(10), args.pop("parents"), args.pop("fps"), **args)


def test_real_xia_clip_renders_quickly(xia_dir, tmp_path):
    pybvh = pytest.importorskip("pybvh")
    clip = pybvh.read_bvh_file(xia_dir / "neutral_01_000.bvh")
    parents = np.full(clip.joint_count, -1)
    for child, parent in clip.edges:
        parents[child] = parent
    positions = clip.joint_positions()[:300]
    start = time.perf_counter()
    path = render_gif(tmp_path / "xia.gif", positions, parents, clip.fps, names=clip.joint_names)
    elapsed = time.perf_counter() - start
    frames, _ = gif_frames(path)
    assert len(frames) == 75  # 300 frames at 120 fps shown at 30 fps
    assert elapsed < 5.0  # about 0.15 s on one core; generous for a shared CI machine
    top, bottom, left, right = extent(mask(frames[-1], scene.LEFT))
    assert 0 < top < bottom < 319 and 0 < left < right < 319


def test_mp4_has_every_frame_and_the_sound_for_as_long(tmp_path):
    import av

    from walkdiff.preview.video import write_mp4

    frames = [Image.new("RGB", (321, 241), (10 * k, 100, 200)) for k in range(25)]  # odd sizes: cropped
    rate = 16000
    speech = 0.3 * np.sin(2 * np.pi * 220 * np.arange(rate) / rate)  # 1 s
    path = write_mp4(tmp_path / "clip.mp4", frames, 25, (speech, rate))
    with av.open(str(path)) as container:
        video, sound = container.streams.video[0], container.streams.audio[0]
        assert (video.codec_context.name, sound.codec_context.name) == ("h264", "aac")
        assert (video.width, video.height) == (320, 240)
        assert float(video.duration * video.time_base) == pytest.approx(1.0)
        assert float(sound.duration * sound.time_base) == pytest.approx(1.0, abs=0.07)  # AAC frames of 64 ms
        assert sum(1 for _ in container.decode(video=0)) == 25
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_a_long_clip_gets_a_preview_of_its_first_seconds(tmp_path):
    """20 min at 60 fps: the GIF shows the first 2 s (at 30 fps), the same frames a short clip's does."""
    cap = render.PreviewCap(seconds=2)
    long_gif = render_gif(tmp_path / "long.gif", walker(72_000), PARENTS, 60, cap=cap)
    short_gif = render_gif(tmp_path / "short.gif", walker(120), PARENTS, 60)
    assert long_gif.read_bytes() == short_gif.read_bytes()
    assert len(gif_frames(long_gif)[0]) == 60
    assert cap.describe(72_000, 60) == {
        "seconds": 2.0, "of_seconds": 1200.0, "capped": True, "note": "first 2 s of 1200 s"
    }  # fmt: skip
    assert cap.describe(90, 60)["note"] == "all 1.5 s" and not cap.describe(90, 60)["capped"]


def test_the_pixel_budget_shortens_previews_of_many_panels(tmp_path):
    cap = render.PreviewCap(seconds=20, pixels=10 * 3 * 64 * 64)  # 10 GIF frames of 3 panels
    assert cap.frames(6000, 60, panels=3, size=(64, 64)) == 20  # 10 GIF frames, every 2nd clip frame
    assert cap.frames(6000, 60, panels=1, size=(64, 64)) == 60
    gif = render_gif(tmp_path / "three.gif", [walker(600)] * 3, PARENTS, 60, size=(64, 64), cap=cap)
    assert len(gif_frames(gif)[0]) == 10
    for seconds in (0, -1, float("nan"), float("inf")):
        with pytest.raises(WalkdiffError, match="--preview-seconds must be a positive number"):
            render.PreviewCap(seconds)
