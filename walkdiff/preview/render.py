"""Stick-figure previews of motion: an animated GIF (and the same as MP4), or a PNG filmstrip of key poses.

A fixed three-quarter camera looks at each clip and follows its root horizontally, so that long walks stay
in frame; the ground grid is fixed in the world and scrolls underneath, and the root's recent path is drawn
on the ground as a fading trail. Several clips are shown side by side (or in rows of `columns`) at one
common scale. Drawing goes straight into a palette ("P") image, which needs no colour quantisation and
keeps GIF writing fast. The camera, colours and drawing are `walkdiff.preview.scene`'s.

`Marks` adds what a user needs to judge motion at a glance: contact marks under planted (and sliding)
feet, a facing arrow on the ground, a ruler in metres with the grid spacing in metres, and a legend.
`render_strobe` draws the still: each clip as a chronophotograph (several poses of the whole clip on one
fixed view), which shows gait, pace and foot placement without animation.

Axis convention, the same in every picture walkdiff draws (GIF, MP4, still and `walkdiff walk`'s
top-down plot): Y is up, the ground is XZ, and the ground is seen from above and in front, with +X
towards the right of the picture and +Z towards the viewer (down the picture). The GIF's camera turns
35 degrees about Y from that view (+X right and a little away, +Z down and a little left); the
top-down plot shows it exactly (x to the right, z downwards).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
from PIL import ImageDraw

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_atomic
from walkdiff.motion.mirror import name_pairs
from walkdiff.preview.scene import NO_MARKS, YAW, Color, Marks, Scene

TRAIL_SECONDS = 3.0  # of the root's path behind each animated body
MAX_GIF_FPS = 50  # GIF delays are in 1/100 s, and browsers slow down anything shorter than 20 ms
PREVIEW_SECONDS = 20.0  # a preview shows a clip's first 20 s: enough to judge the motion, a few MB of GIF
# Pixels of all of a GIF's frames (1 byte each in palette mode; Pillow holds every frame until it writes):
# 20 s of one 320x320 panel at 30 fps is 61 M; previews of several panels side by side get shorter.
PREVIEW_PIXELS = 100_000_000


@dataclass(frozen=True)
class PreviewCap:
    """How much of a clip a preview shows: its first `seconds`, and no more GIF frames than fit in
    `pixels` (frames x width x height of all panels), so that a preview's memory and file stay bounded
    whatever the clip's length."""

    seconds: float = PREVIEW_SECONDS
    pixels: int = PREVIEW_PIXELS

    def __post_init__(self) -> None:
        if not (math.isfinite(self.seconds) and self.seconds > 0):
            raise WalkdiffError(f"--preview-seconds must be a positive number of seconds, got {self.seconds}")
        if self.pixels < 1:
            raise WalkdiffError(f"the preview pixel budget must be positive, got {self.pixels}")

    def frames(
        self, clip_frames: int, fps: float, panels: int = 1, size: tuple[int, int] = (320, 320),
        max_fps: float = 30,
    ) -> int:  # fmt: skip
        """Frames (at the clip's fps) of a `clip_frames` clip that a GIF of `panels` panels shows."""
        step = gif_step(fps, max_fps)
        gif_frames = max(1, self.pixels // (panels * size[0] * size[1]))
        return max(1, min(clip_frames, math.floor(self.seconds * fps + 1e-9), gif_frames * step))

    def describe(self, clip_frames: int, fps: float, panels: int = 1, **gif) -> dict:
        """What a preview of a `clip_frames` clip shows, for manifests and the console."""
        shown = self.frames(clip_frames, fps, panels, **gif)
        seconds, total = shown / fps, clip_frames / fps
        note = f"first {seconds:.3g} s of {total:.4g} s" if shown < clip_frames else f"all {total:.4g} s"
        return {
            "seconds": round(seconds, 3),
            "of_seconds": round(total, 3),
            "capped": shown < clip_frames,
            "note": note,
        }


DEFAULT_PREVIEW = PreviewCap()


def gif_step(fps: float, max_fps: float) -> int:
    """Every how many frames of a clip at `fps` a GIF playing at most `max_fps` shows one."""
    return math.ceil(fps / max_fps - 1e-9)


def render_gif(
    path: str | Path,
    positions: np.ndarray | Sequence[np.ndarray],
    parents: Sequence[int] | np.ndarray,
    fps: float,
    *,
    names: Sequence[str] | None = None,
    titles: Sequence[str] | None = None,
    colors: Sequence[Color] | None = None,
    max_fps: float = 30,
    size: tuple[int, int] = (320, 320),
    trail: bool = True,
    cap: PreviewCap = DEFAULT_PREVIEW,
    video: bool = False,
    audio: tuple[np.ndarray, int] | None = None,
    marks: Marks = NO_MARKS,
    paths: Sequence[np.ndarray | None] | None = None,
    columns: int | None = None,
) -> Path:
    """Write an animated GIF of one or more clips side by side and return its path.

    positions: world joint positions (F, J, 3) with Y up, a list of such arrays (one panel each; clips may
        differ in length, a shorter one holds its last pose), or an (N, F, J, 3) batch.
    parents: (J,) parent index per joint, -1 for the root (joint 0).
    names: joint names; when given, left limbs are drawn blue, right limbs orange and the head as a circle.
    titles / colors: one per clip; a colour replaces the body colour (and that of the trail).
    max_fps: frames are skipped so that the GIF plays at most this fast, at the clip's real speed.
    size: (width, height) of one panel in pixels.
    cap: the clips' first seconds shown (`PreviewCap.describe` says how much, for a manifest).
    video: also write the same frames as an MP4 beside it (`path` with .mp4), with `audio` (mono
        samples, rate) from the clip's start as its sound, cut to the preview's length.
    marks: contact marks, facing arrow, ruler and legend (`Marks`).
    paths: per clip, None or a requested path (N, 2) of ground points (x, z) drawn on the ground.
    columns: panels per row (all in one row by default); clip i is at row i // columns.
    """
    clips, parents = _check_clips(positions, parents, names, titles, colors, size)
    _check_extras(marks, names, paths, columns, len(clips), len(parents))
    if not (math.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"fps must be a positive number, got {fps}")
    if not (0 < max_fps <= MAX_GIF_FPS):
        raise WalkdiffError(
            f"max_fps must be in (0, {MAX_GIF_FPS}] (GIF timing is in 1/100 s), got {max_fps}"
        )

    shown = cap.frames(max(len(c) for c in clips), fps, len(clips), size, max_fps)
    clips = [c[:shown] for c in clips]
    step = gif_step(fps, max_fps)
    sources = range(0, shown, step)
    scene = Scene(
        clips, parents, names, colors, size, trail_frames=round(TRAIL_SECONDS * fps) if trail else 0,
        marks=marks, fps=fps, paths=paths,
    )  # fmt: skip
    frames = []
    for k, source in enumerate(sources):
        clock = f"{k * step / fps:.2f} s"
        image = scene.canvas(len(clips), columns, clock)
        for i in range(len(clips)):
            image.paste(
                scene.panel(i, source, None if titles is None else titles[i]), scene.place(i, columns)
            )
        if not marks.legend:
            draw = ImageDraw.Draw(image)
            draw.text((6, size[1] - 6), clock, fill=scene.text_ink, font=scene.font, anchor="ld")
        frames.append(image)

    # Delays rounded on the cumulative clock, so the whole GIF lasts as long as the motion.
    clock = np.round(np.arange(len(frames) + 1) * step / fps * 100) * 10
    delays = [int(d) for d in np.diff(clock)]

    def save(f: IO[bytes]) -> None:
        frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:], duration=delays, loop=0)

    if video:
        from walkdiff.preview.video import write_mp4

        if audio is not None:
            samples, rate = audio
            audio = (samples[: round(len(frames) * step / fps * rate)], rate)
        write_mp4(Path(path).with_suffix(".mp4"), frames, fps / step, audio)
    return write_atomic(path, save)


def render_png(
    path: str | Path,
    positions: np.ndarray | Sequence[np.ndarray],
    parents: Sequence[int] | np.ndarray,
    *,
    frames: int = 6,
    names: Sequence[str] | None = None,
    titles: Sequence[str] | None = None,
    colors: Sequence[Color] | None = None,
    size: tuple[int, int] = (200, 240),
) -> Path:
    """Write a filmstrip of `frames` evenly spaced poses (one row per clip) as PNG and return its path.

    Arguments as for `render_gif`; `size` is one pose's cell. Each cell is labelled with its frame index
    and the clip's trail shows the whole path walked so far.
    """
    clips, parents = _check_clips(positions, parents, names, titles, colors, size)
    if frames < 1:
        raise WalkdiffError(f"frames must be at least 1, got {frames}")
    scene = Scene(clips, parents, names, colors, size, trail_frames=max(len(c) for c in clips))
    image = scene.canvas(frames * len(clips), frames)
    for i, clip in enumerate(clips):
        picks = np.linspace(0, len(clip) - 1, frames).round().astype(int)
        for col, source in enumerate(picks):
            title = f"frame {source}" if titles is None else f"{titles[i]}  frame {source}"
            image.paste(scene.panel(i, int(source), title), (col * size[0], i * size[1]))
    return write_atomic(path, lambda f: image.save(f, format="PNG", optimize=False))


def render_strobe(
    path: str | Path,
    positions: np.ndarray | Sequence[np.ndarray],
    parents: Sequence[int] | np.ndarray,
    fps: float,
    *,
    poses: int = 7,
    names: Sequence[str] | None = None,
    titles: Sequence[str] | None = None,
    colors: Sequence[Color] | None = None,
    size: tuple[int, int] = (480, 220),
    marks: Marks = NO_MARKS,
    paths: Sequence[np.ndarray | None] | None = None,
    columns: int | None = None,
    turn: bool = False,
) -> Path:
    """Write a still of each clip as a chronophotograph and return its path (PNG).

    Each panel is a fixed view of the whole clip: `poses` evenly spaced poses, older ones fainter, the
    root's path and (with `marks`) every contact mark of the clip, which together show step length,
    pace and foot skating. `turn` turns each clip about the vertical so that it walks from left to right
    (a clip walking at the camera would hide its own poses); leave it off to keep world directions, as
    walk previews must for their paths. Other arguments as for `render_gif`.
    """
    clips, parents = _check_clips(positions, parents, names, titles, colors, size)
    _check_extras(marks, names, paths, columns, len(clips), len(parents))
    if poses < 1:
        raise WalkdiffError(f"poses must be at least 1, got {poses}")
    if not (math.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"fps must be a positive number, got {fps}")
    if turn:
        if paths is not None:
            raise WalkdiffError("render_strobe: turn=True would turn the clips away from their paths")
        clips = [_turned_to_screen(c) for c in clips]
    scene = Scene(
        clips, parents, names, colors, size, trail_frames=max(len(c) for c in clips), marks=marks,
        fps=fps, paths=paths, follow=False, shades=poses,
    )  # fmt: skip
    seconds = max(len(c) for c in clips) / fps
    image = scene.canvas(len(clips), columns, f"{poses} poses over {seconds:.1f} s")
    for i in range(len(clips)):
        image.paste(scene.strobe(i, poses, None if titles is None else titles[i]), scene.place(i, columns))
    return write_atomic(path, lambda f: image.save(f, format="PNG", optimize=False))


def _turned_to_screen(clip: np.ndarray) -> np.ndarray:
    """The clip turned about the vertical through its first root so that it walks to the screen's right
    (the camera's right axis is (cos YAW, 0, -sin YAW)); a clip that goes nowhere is left as it is."""
    travel = clip[-1, 0, [0, 2]] - clip[0, 0, [0, 2]]
    if np.hypot(*travel) < 1e-9:
        return clip
    angle = math.atan2(-math.sin(YAW), math.cos(YAW)) - math.atan2(travel[1], travel[0])
    c, s = math.cos(angle), math.sin(angle)
    # Rotation of (x, z) by `angle` in the ground plane, as a 3-D turn about Y.
    turn = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    pivot = np.array([clip[0, 0, 0], 0.0, clip[0, 0, 2]])
    return (clip - pivot) @ turn.T + pivot


def _check_extras(
    marks: Marks,
    names: Sequence[str] | None,
    paths: Sequence[np.ndarray | None] | None,
    columns: int | None,
    num_clips: int,
    num_joints: int,
) -> None:
    if marks.facing and names is None:
        raise WalkdiffError("the facing arrow needs joint names (to find the left/right hips)")
    if marks.facing and not name_pairs(names):
        raise WalkdiffError("the facing arrow needs left/right joint pairs; none found in the joint names")
    if any(not 0 <= j < num_joints for j in marks.feet):
        raise WalkdiffError(f"marks.feet must be joint indices below {num_joints}, got {marks.feet}")
    if marks.feet and marks.contact is None:
        raise WalkdiffError("marks.feet needs marks.contact (the contact thresholds)")
    if marks.metres_per_unit is not None and not (0 < marks.metres_per_unit < math.inf):
        raise WalkdiffError(f"marks.metres_per_unit must be positive, got {marks.metres_per_unit}")
    if paths is not None:
        if len(paths) != num_clips:
            raise WalkdiffError(
                f"paths must have {num_clips} entries (None or (N, 2) points), got {len(paths)}"
            )
        for i, points in enumerate(paths):
            if points is not None and (np.ndim(points) != 2 or np.shape(points)[1] != 2 or len(points) < 2):
                raise WalkdiffError(f"paths[{i}] must be (N, 2) ground points (x, z), N >= 2")
    if columns is not None and columns < 1:
        raise WalkdiffError(f"columns must be at least 1, got {columns}")


def _check_clips(
    positions: np.ndarray | Sequence[np.ndarray],
    parents: Sequence[int] | np.ndarray,
    names: Sequence[str] | None,
    titles: Sequence[str] | None,
    colors: Sequence[Color] | None,
    size: tuple[int, int],
) -> tuple[list[np.ndarray], np.ndarray]:
    parents = np.asarray(parents)
    if parents.ndim != 1 or parents.size == 0 or not np.issubdtype(parents.dtype, np.integer):
        raise WalkdiffError(f"parents must be a 1-D integer array (J,), got shape {parents.shape}")
    num_joints = len(parents)
    bad = [j for j, p in enumerate(parents) if not (-1 <= p < num_joints) or p == j or (p == -1) != (j == 0)]
    if bad:
        raise WalkdiffError(
            f"parents must be -1 for the root (joint 0) and a valid joint elsewhere; bad at {bad}"
        )
    if isinstance(positions, (list, tuple)):
        clips = [np.asarray(p, dtype=np.float64) for p in positions]
    else:
        array = np.asarray(positions, dtype=np.float64)
        clips = list(array) if array.ndim == 4 else [array]
    if not clips:
        raise WalkdiffError("positions holds no clip")
    for i, clip in enumerate(clips):
        if clip.ndim != 3 or clip.shape[0] < 1 or clip.shape[1:] != (num_joints, 3):
            raise WalkdiffError(
                f"positions[{i}] must have shape (frames, {num_joints}, 3) with frames >= 1 and"
                f" {num_joints} = len(parents), got {clip.shape}"
            )
        if not np.isfinite(clip).all():
            raise WalkdiffError(f"positions[{i}] contains NaN or infinite values")
    for label, given, count in (("names", names, num_joints), ("titles", titles, len(clips))):
        if given is not None and len(given) != count:
            raise WalkdiffError(f"{label} must have {count} entries, got {len(given)}")
    if colors is not None and (len(colors) != len(clips) or any(len(c) != 3 for c in colors)):
        raise WalkdiffError(f"colors must be {len(clips)} (r, g, b) triples, one per clip")
    if len(size) != 2 or min(size) < 32:
        raise WalkdiffError(f"size must be (width, height) of at least 32 pixels each, got {size}")
    return clips, parents
