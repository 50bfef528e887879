"""Previews a user judges motion from: contact marks, facing arrow, ruler, legend, requested paths, the
style grid of real and generated clips, and one axis convention in the GIF and the top-down plot."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import synthetic
from PIL import Image
from test_render import extent, gif_frames, mask

from walkdiff.callbacks.samples import SampleClips, real_references
from walkdiff.common.errors import WalkdiffError
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.motion.path import Polyline
from walkdiff.motion.profile import ContactSpec
from walkdiff.preview import scene
from walkdiff.preview.render import Marks, render_gif, render_strobe
from walkdiff.walker.plots import plot_paths

NAMES = ["Hips", "LeftUpLeg", "LeftFoot", "RightUpLeg", "RightFoot", "Spine", "Head"]
PARENTS = np.array([-1, 0, 1, 0, 3, 0, 5])
FEET = (2, 4)
CYCLE = 40  # frames: left planted 0-14, both feet up 15-19, right planted 20-34, both up 35-39
LEFT_PLANTED, BOTH_UP, RIGHT_PLANTED = 8, 17, 27


def stepper(frames: int = 80, fps: float = 30, direction: float = 1.0, unit: float = 1.0) -> np.ndarray:
    """A figure (metres / `unit`, Y up) walking and facing along direction * X at 1.2 m/s, whose feet are
    planted (still, on the ground) or up (0.3 m high, moving) on known frames (see CYCLE)."""
    t = np.arange(frames) / fps
    root = np.stack([direction * 1.2 * t, np.full(frames, 0.9), np.zeros(frames)], axis=-1)
    # Facing +X with Y up, the body's right is +Z: the left hip is on -Z (mirrored for -X).
    side = np.array([0.0, 0.0, 0.12 * direction])
    phase = np.arange(frames) % CYCLE
    feet = []
    for sign, planted in ((-1, phase < 15), (1, (phase >= 20) & (phase < 35))):
        x = np.where(planted, 0.0, root[:, 0] + 0.3 * direction)
        # A planted foot stays where it landed: the root's x at the start of its stance.
        start = np.maximum.accumulate(np.where(planted & ~np.r_[False, planted[:-1]], np.arange(frames), 0))
        x = np.where(planted, root[start, 0], x)
        feet.append(np.stack([x, np.where(planted, 0.0, 0.3), np.full(frames, sign * side[2])], axis=-1))
    hips_l, hips_r = root - side, root + side
    spine = root + [0.0, 0.5, 0.0]
    joints = [root, hips_l, feet[0], hips_r, feet[1], spine, spine + [0.0, 0.25, 0.0]]
    return np.stack(joints, axis=1) / unit


def marks(unit: float = 1.0, **kwargs) -> Marks:
    contact = ContactSpec("LeftFoot", "LeftFoot", "RightFoot", "RightFoot", 0.34 / unit, 0.034 / unit)
    return Marks(FEET, contact, unit, **({"facing": True, "legend": True} | kwargs))


def panel_frames(path) -> list[np.ndarray]:
    return gif_frames(path)[0]


def test_contact_marks_show_on_planted_frames_only(tmp_path):
    gif = render_gif(tmp_path / "c.gif", stepper(), PARENTS, 30, names=NAMES, marks=marks(facing=False))
    frames = panel_frames(gif)
    panel = slice(0, 320)
    for frame, limb in ((LEFT_PLANTED, scene.LEFT), (RIGHT_PLANTED, scene.RIGHT)):
        image = frames[frame][:320, panel]
        dots = mask(image, scene.PLANTED)
        assert dots.sum() > 10, frame
        # Under the planted foot: the dot is where that leg ends, not under the other one.
        _, foot_row, _, _ = extent(mask(image, limb))
        rows, cols = np.nonzero(dots)
        assert abs(rows.mean() - foot_row) < 8
        leg_cols = np.nonzero(mask(image, limb)[foot_row - 2 : foot_row + 1])[1]
        assert abs(cols.mean() - leg_cols.mean()) < 8
    assert mask(frames[BOTH_UP][:320, panel], scene.PLANTED).sum() == 0
    assert mask(frames[CYCLE + BOTH_UP][:320, panel], scene.PLANTED).sum() == 0


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_facing_arrow_points_the_way_the_body_faces(tmp_path, direction):
    """The camera shows +X to the right (and a little up): a body facing +X gets an arrow to the right
    of its root, one facing -X an arrow to the left."""
    clip = stepper(direction=direction)
    frames = panel_frames(render_gif(tmp_path / "f.gif", clip, PARENTS, 30, names=NAMES, marks=marks()))
    for frame in frames[::10]:
        rows, cols = np.nonzero(mask(frame[:320], scene.FACING))
        assert len(cols) > 20
        assert np.sign(cols.mean() - 160) == direction and abs(cols.mean() - 160) > 15
    still = render_strobe(tmp_path / "f.png", clip, PARENTS, 30, names=NAMES, marks=marks())
    with Image.open(still) as image:
        pixels = np.asarray(image.convert("RGB"))[:220]  # the panel, without the legend
    arrow = np.nonzero(mask(pixels, scene.FACING))[1]
    head_cols = np.nonzero(mask(pixels, scene.BODY))[1]  # the last pose is the strongest body colour
    assert np.sign(arrow.mean() - head_cols.mean()) == direction


def test_no_facing_arrow_where_the_hips_coincide(tmp_path):
    """A collapsed body (an untrained model's) has no facing: no arrow, and no error either."""
    clip = stepper()
    clip[:40, 3] = clip[:40, 1]  # both hips and both feet on one point for the first 40 frames
    clip[:40, 4] = clip[:40, 2]
    frames = panel_frames(render_gif(tmp_path / "x.gif", clip, PARENTS, 30, names=NAMES, marks=marks()))
    assert mask(frames[10][:320], scene.FACING).sum() == 0
    assert mask(frames[60][:320], scene.FACING).sum() > 20
    with pytest.raises(WalkdiffError, match="needs joint names"):
        render_gif(tmp_path / "x.gif", stepper(), PARENTS, 30, marks=marks())


@pytest.mark.parametrize("unit", [1.0, 0.01])
def test_the_ruler_is_one_metre_on_the_ground_whatever_the_units(tmp_path, unit):
    """A standing figure whose legs are 0.9 m long: on screen (orthographic, 18 degrees down) a vertical
    leg is 0.9 cos(18 deg) of the ruler's metre, in metres or in centimetres alike."""
    standing = np.repeat(stepper()[:1], 10, axis=0)
    standing[:, 2] = standing[:, 1] - [0, 0.9, 0]  # feet straight below the hips
    standing[:, 4] = standing[:, 3] - [0, 0.9, 0]
    gif = render_gif(tmp_path / "r.gif", standing / unit, PARENTS, 30, names=NAMES, marks=marks(unit))
    frame = panel_frames(gif)[0]
    panel = frame[:320]
    ruler = mask(panel, scene.RULER)
    row = np.bincount(np.nonzero(ruler)[0]).argmax()  # the ruler's line
    cols = np.nonzero(ruler[row])[0]
    metre = cols.max() - cols.min()
    top, bottom, _, _ = extent(mask(panel, scene.LEFT))
    assert (bottom - top) / metre == pytest.approx(0.9 * np.cos(scene.PITCH), rel=0.06)
    # The legend below the panel: every mark's sample colour, and the ruler's.
    legend = frame[320:]
    for color in (scene.LEFT, scene.RIGHT, scene.PLANTED, scene.FACING, scene.RULER):
        assert mask(legend, color).sum() > 5, color


def standing(frames: int = 3) -> np.ndarray:
    """The stepper's body standing at the origin with both feet on the ground below the hips."""
    clip = np.repeat(stepper()[:1], frames, axis=0)
    clip[..., [0, 2]] -= clip[:1, :1, [0, 2]]
    clip[:, 2] = clip[:, 1] * [1, 0, 1]
    clip[:, 4] = clip[:, 3] * [1, 0, 1]
    return clip


def test_requested_path_is_drawn_where_the_path_lies(tmp_path):
    """A body stands with its feet 0.12 m either side of z = 0: a path along X on z = 0 passes between
    its feet; one 0.4 m towards the viewer (+Z) lies below both, with the same slope."""
    on = np.array([[-5.0, 0.0], [10.0, 0.0]])
    beside = on + [0.0, 0.4]
    gif = render_gif(tmp_path / "p.gif", [standing()] * 2, PARENTS, 30, names=NAMES, paths=[on, beside])
    frame = panel_frames(gif)[0]
    under, aside = mask(frame[:, :320], scene.PATH), mask(frame[:, 320:], scene.PATH)
    left_foot = extent(mask(frame[:, :320], scene.LEFT))[1]  # on -Z: further away, higher up
    right_foot = extent(mask(frame[:, :320], scene.RIGHT))[1]
    assert left_foot < right_foot
    middle = np.nonzero(under[:, 155:166].any(axis=1))[0]
    assert len(middle) and left_foot < middle.mean() < right_foot
    below = np.nonzero(aside[:, 155:166].any(axis=1))[0]
    assert len(below) and below.min() > right_foot + 10
    # Straight lines on the ground, parallel on screen.
    slope = [np.polyfit(*np.nonzero(m)[::-1], 1)[0] for m in (under, aside)]
    assert slope[0] == pytest.approx(slope[1], abs=0.02)


def test_plot_and_gif_share_one_axis_convention(tmp_path):
    """An L path: +Z first, then +X. In the top-down plot and in the GIF alike, the +Z leg goes down
    the picture and the +X leg then goes right."""
    corner = np.array([[0.0, 0.0], [0.0, 0.8], [0.8, 0.8]])
    plot = plot_paths(tmp_path / "plot.png", [("L", Polyline.of(corner), [])])
    with Image.open(plot) as image:
        pixels = np.asarray(image.convert("RGB"))
    assert pixels.shape[1] >= 800
    start = np.argwhere(mask(pixels, (0x1A, 0x98, 0x50))).mean(0)  # the start marker
    end = np.argwhere(mask(pixels, (0xD7, 0x19, 0x1C))).mean(0)  # the end marker
    assert end[0] - start[0] > 50 and end[1] - start[1] > 50  # end: down (+Z) and right (+X) of the start

    frame = panel_frames(render_gif(tmp_path / "l.gif", standing(), PARENTS, 30, paths=[corner]))[0]
    rows, cols = np.nonzero(mask(frame, scene.PATH))
    feet_row = np.nonzero(mask(frame, scene.BODY))[0].max()  # the start: the root's ground point
    lowest = rows.argmax()  # the corner: +Z from the start goes down the picture
    assert rows[lowest] > feet_row + 30
    assert cols.max() > cols[lowest] + 30  # and +X from the corner goes right


def test_marks_of_a_profile_name_its_feet_and_units():
    profile = synthetic.xia_profile(synthetic.walking())
    marks = Marks.of(profile)
    names = profile.canonical_skeleton.names
    assert [names[j] for j in marks.feet] == ["LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase"]
    assert marks.contact == profile.contacts and marks.metres_per_unit == profile.metres_per_unit
    assert marks.facing and marks.legend


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny generator fitted for two steps on synthetic walks, and its data module."""
    from walkdiff.models.styled_ddpm import StyledMotionDiffusion

    root = tmp_path_factory.mktemp("grid")
    synthetic.xia_like_folder(root, walk_clips=8, frames=240)
    dm = MotionDataModule(
        root=str(root), cache_dir=str(root / "cache"), batch_size=8, window=24, preprocess_workers=1
    )
    L.seed_everything(0)
    model = StyledMotionDiffusion(dm.spec, d_model=32, layers=1, heads=2, dropout=0.0, lambda_adv=0.0)
    synthetic.quiet_trainer(max_steps=2, limit_val_batches=0).fit(model, dm)
    return model.eval(), dm


def test_style_grid_shows_real_beside_generated_long_and_readable(tiny, tmp_path):
    model, dm = tiny
    styles = list(model.spec["styles"])
    callback = SampleClips(content="walk", sampler="ddim", steps=2, video=True)
    callback.references = real_references(dm, styles, "walk")
    assert sorted(callback.references) == ["angry", "old"]  # the synthetic data's two styles
    # The same reference every time: the longest training clip of the style and content.
    again = real_references(dm, styles, "walk")
    for style, (name, features) in callback.references.items():
        assert name == again[style][0] and name.startswith(style)
        assert len(features) == max(
            len(f) for c, n, f in dm.split_features("train") if n.startswith(style + "_0")
        )
    # The synthetic data has walks of two of Xia's eight styles: the others get the angry clip here, so
    # the layout of a full grid can be checked (the real run's warning is checked below).
    callback.references = {style: callback.references["angry"] for style in styles} | callback.references
    files = {f.name: f for f in callback.write(model, None, "", folder=tmp_path / "full")}
    assert {f"{s}_walk.bvh" for s in styles} | {"styles.gif", "styles.mp4", "styles.png"} == set(files)
    with Image.open(files["styles.png"]) as still:
        width, height = still.size
    # Two columns (real | generated), one row per style, at most ~1000 px wide, panels >= 300 px.
    assert width <= 1000 and width / 2 >= 300
    assert height >= len(styles) * 200
    frames, delays = gif_frames(files["styles.gif"])
    assert frames[0].shape[1] <= 1000 and frames[0].shape[1] / 2 >= 300
    assert frames[0].shape[0] >= len(styles) * 250
    assert sum(delays) / 1000 >= 3.0  # seconds of motion


def test_style_grid_without_a_real_clip_says_so(tiny, tmp_path, caplog):
    model, dm = tiny
    callback = SampleClips(content="walk", sampler="ddim", steps=2)
    callback.references = real_references(dm, list(model.spec["styles"]), "walk")
    files = {f.name: f for f in callback.write(model, None, "", folder=tmp_path)}
    assert "styles.mp4" not in files  # GIF only by default
    assert "no real walk clip of childlike, depressed" in caplog.text
    with Image.open(files["styles.png"]) as still:
        assert still.size[0] <= 1000 and still.size[0] / 2 >= 300  # generated only, two per row
