"""Stick-figure previews of motion: an animated GIF (and the same as MP4), or a PNG filmstrip of key poses.

A fixed three-quarter camera looks at each clip and follows its root horizontally, so that long walks stay
in frame; the ground grid is fixed in the world and scrolls underneath, and the root's recent path is drawn
on the ground as a fading trail. Several clips are shown side by side at one common scale. Drawing goes
straight into a palette ("P") image, which needs no colour quantisation and keeps GIF writing fast.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from walkdiff.errors import WalkdiffError
from walkdiff.files import write_atomic
from walkdiff.motion.mirror import name_pairs

Color = tuple[int, int, int]

YAW = math.radians(35.0)  # camera azimuth from +Z towards +X: clips walking along X are seen mostly side-on
PITCH = math.radians(18.0)  # camera elevation, enough to see the ground grid and the trail
TRAIL_SECONDS = 3.0
TRAIL_SHADES = 6  # palette entries per fading trail
MAX_GIF_FPS = 50  # GIF delays are in 1/100 s, and browsers slow down anything shorter than 20 ms
PREVIEW_SECONDS = 20.0  # a preview shows a clip's first 20 s: enough to judge the motion, a few MB of GIF
# Pixels of all of a GIF's frames (1 byte each in palette mode; Pillow holds every frame until it writes):
# 20 s of one 320x320 panel at 30 fps is 61 M; previews of several panels side by side get shorter.
PREVIEW_PIXELS = 100_000_000

BACKGROUND: Color = (250, 250, 247)
GRID: Color = (222, 222, 216)
TEXT: Color = (40, 40, 40)
BODY: Color = (55, 55, 55)
LEFT: Color = (33, 102, 172)
RIGHT: Color = (214, 96, 39)


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
    """
    clips, parents = _check_clips(positions, parents, names, titles, colors, size)
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
    scene = _Scene(
        clips, parents, names, colors, size, trail_frames=round(TRAIL_SECONDS * fps) if trail else 0
    )
    frames = []
    for k, source in enumerate(sources):
        image = scene.canvas(len(clips), 1)
        for i in range(len(clips)):
            image.paste(scene.panel(i, source, None if titles is None else titles[i]), (i * size[0], 0))
        clock = f"{k * step / fps:.2f} s"
        ImageDraw.Draw(image).text((6, size[1] - 6), clock, fill=scene.text_ink, font=scene.font, anchor="ld")
        frames.append(image)

    # Delays rounded on the cumulative clock, so the whole GIF lasts as long as the motion.
    clock = np.round(np.arange(len(frames) + 1) * step / fps * 100) * 10
    delays = [int(d) for d in np.diff(clock)]

    def save(f: IO[bytes]) -> None:
        frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:], duration=delays, loop=0)

    if video:
        from walkdiff.video import write_mp4

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
    scene = _Scene(clips, parents, names, colors, size, trail_frames=max(len(c) for c in clips))
    image = scene.canvas(frames, len(clips))
    for i, clip in enumerate(clips):
        picks = np.linspace(0, len(clip) - 1, frames).round().astype(int)
        for col, source in enumerate(picks):
            title = f"frame {source}" if titles is None else f"{titles[i]}  frame {source}"
            image.paste(scene.panel(i, int(source), title), (col * size[0], i * size[1]))
    return write_atomic(path, lambda f: image.save(f, format="PNG", optimize=False))


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


def _sides(names: Sequence[str]) -> list[Color | None]:
    """Limb colour per joint: left and right as the skeleton's mirror pairs are found by name (every
    convention `walkdiff.motion.mirror` knows), None for the centre line and unpaired joints."""
    sides: list[Color | None] = [None] * len(names)
    for left, right in name_pairs(names):
        sides[left], sides[right] = LEFT, RIGHT
    return sides


def _project(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographic camera: (..., 3) points -> screen right, screen up and depth towards the camera."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    right = x * math.cos(YAW) - z * math.sin(YAW)
    depth = x * math.sin(YAW) + z * math.cos(YAW)
    up = y * math.cos(PITCH) - depth * math.sin(PITCH)
    return right, up, depth


def _nice_step(length: float) -> float:
    """Closest value of the form 1, 2 or 5 times a power of ten (a grid spacing that reads well)."""
    power = 10 ** math.floor(math.log10(length))
    return min((m * power for m in (1, 2, 5, 10)), key=lambda s: abs(s - length))


def _mix(color: Color, amount: float) -> Color:
    """`color` faded towards the background; amount 0 is the background, 1 the colour itself."""
    r, g, b = (round(back + (c - back) * amount) for c, back in zip(color, BACKGROUND, strict=True))
    return r, g, b


@dataclass
class _Clip:
    xy: np.ndarray  # (F, J, 2) joint pixels in the clip's panel
    depth: np.ndarray  # (F, J) towards the camera: far bones are drawn first
    root: np.ndarray  # (F, 2) the root's world x, z, which the camera follows
    inks: list[int]  # palette index of the bone ending at each joint
    trail_inks: list[int]  # from faint (oldest) to full


class _Scene:
    """Camera framing, palette and drawing shared by every clip, so that all clips have one scale."""

    def __init__(
        self,
        clips: list[np.ndarray],
        parents: np.ndarray,
        names: Sequence[str] | None,
        colors: Sequence[Color] | None,
        size: tuple[int, int],
        trail_frames: int,
    ):
        self.parents = parents
        self.size = size
        self.trail_frames = trail_frames
        width, height = size
        self.font = ImageFont.load_default(size=max(9, round(height / 22)))
        self.line_width = max(2, round(height / 110))
        heads = [j for j, n in enumerate(names or []) if n.lower() == "head"]
        self.head = heads[0] if heads else None

        # Each clip is seen from above its own root (horizontally) and its own lowest point (vertically).
        relative = []
        for clip in clips:
            anchor = np.stack([clip[:, 0, 0], np.full(len(clip), clip[..., 1].min()), clip[:, 0, 2]], axis=-1)
            relative.append(clip - anchor[:, None, :])
        screen = [_project(r) for r in relative]
        stature = max(max(float(r[..., 1].max()) for r in relative), 1e-9)
        self.head_radius = 0.055 * stature  # world units until the scale is known
        reach = max(float(np.abs(right).max()) for right, _, _ in screen)
        highest = max(float(up.max()) for _, up, _ in screen) + (1.8 * self.head_radius if heads else 0.0)
        lowest = min(0.0, *(float(up.min()) for _, up, _ in screen))
        # Room for the title above and for some ground (grid, trail) below the feet.
        top, bottom, side = 1.6 * self.font.size, 0.14 * height, 0.05 * width
        self.scale = min((width / 2 - side) / max(reach, 1e-9), (height - top - bottom) / (highest - lowest))
        self.origin = np.array([width / 2, top + highest * self.scale])  # pixel of the ground below the root
        self.head_radius *= self.scale

        self.palette: dict[Color, int] = {BACKGROUND: 0}  # index 0: new images start as background
        self.grid_ink = self.ink(GRID)
        self.text_ink = self.ink(TEXT)
        sides = [None] * len(parents) if names is None else _sides(names)
        self.clips = []
        for i, (clip, rel, (_, _, depth)) in enumerate(zip(clips, relative, screen, strict=True)):
            body = BODY if colors is None else tuple(int(c) for c in colors[i])
            self.clips.append(
                _Clip(
                    xy=self._to_pixels(rel),
                    depth=depth,
                    root=clip[:, 0, [0, 2]],
                    inks=[self.ink(s or body) for s in sides],
                    trail_inks=[
                        self.ink(_mix(body, (k + 1) / (TRAIL_SHADES + 1))) for k in range(TRAIL_SHADES)
                    ],
                )
            )
        self.grid_step = _nice_step(stature / 2)
        self.grid = self._grid_image()

    def ink(self, color: Color) -> int:
        """Palette index of a colour, added on first use (only while setting up, before any image exists)."""
        if color not in self.palette:
            if len(self.palette) == 256:
                raise WalkdiffError("too many clip colours for one palette (at most about 30 clips)")
            self.palette[color] = len(self.palette)
        return self.palette[color]

    def canvas(self, columns: int, rows: int) -> Image.Image:
        """A background image of `columns` x `rows` panels."""
        return self._blank((columns * self.size[0], rows * self.size[1]))

    def _blank(self, size: tuple[int, int]) -> Image.Image:
        image = Image.new("P", size, 0)
        image.putpalette([v for color in self.palette for v in color])
        return image

    def _grid_image(self) -> Image.Image:
        """The ground grid seen from a root at the world origin, with a margin of one grid cell all round.

        The grid is periodic, so the view from any root is a crop of this image, shifted by the root's
        position modulo one cell: one crop per frame instead of dozens of lines.
        """
        self.margin = math.ceil(self.grid_step * self.scale * 1.5) + 1
        width, height = self.size
        image = self._blank((width + 2 * self.margin, height + 2 * self.margin))
        # The ground is foreshortened by sin(PITCH): reach far enough to cover the whole panel.
        reach = (max(width, height) + 2 * self.margin) / self.scale / math.sin(PITCH)
        cells = math.ceil(reach / self.grid_step)
        draw = ImageDraw.Draw(image)
        for k in range(-cells, cells + 1):
            fixed = k * self.grid_step
            for ends in ([[fixed, 0, -reach], [fixed, 0, reach]], [[-reach, 0, fixed], [reach, 0, fixed]]):
                pixels = self._to_pixels(np.asarray(ends, dtype=np.float64)) + self.margin
                draw.line([tuple(pixels[0]), tuple(pixels[1])], fill=self.grid_ink, width=1)
        return image

    def panel(self, index: int, frame: int, title: str | None) -> Image.Image:
        """Clip `index` at `frame` (its last frame if shorter) on its own panel, so nothing spills over."""
        clip = self.clips[index]
        frame = min(frame, len(clip.xy) - 1)
        cell = np.mod(clip.root[frame], self.grid_step)
        shift = (
            np.round(self._to_pixels(np.array([cell[0], 0.0, cell[1]])) - self.origin).astype(int)
            + self.margin
        )
        image = self.grid.crop((shift[0], shift[1], shift[0] + self.size[0], shift[1] + self.size[1]))
        draw = ImageDraw.Draw(image)
        if self.trail_frames and frame:
            self._draw_trail(draw, clip, frame)
        joints = clip.xy[frame]
        depth = clip.depth[frame]
        for j in sorted(range(1, len(self.parents)), key=lambda j: depth[j] + depth[self.parents[j]]):
            draw.line(
                [tuple(joints[self.parents[j]]), tuple(joints[j])], fill=clip.inks[j], width=self.line_width
            )
        if self.head is not None:
            # The head joint sits at the base of the skull: put the circle a little further along the neck.
            up = joints[self.head] - joints[max(self.parents[self.head], 0)]
            centre = joints[self.head] + up / max(float(np.hypot(*up)), 1e-9) * self.head_radius * 0.8
            box = [tuple(centre - self.head_radius), tuple(centre + self.head_radius)]
            draw.ellipse(box, fill=0, outline=clip.inks[self.head], width=self.line_width)
        if title:
            draw.text((self.size[0] / 2, 3), title, fill=self.text_ink, font=self.font, anchor="ma")
        draw.rectangle([(0, 0), (self.size[0] - 1, self.size[1] - 1)], outline=self.grid_ink)
        return image

    def _draw_trail(self, draw: ImageDraw.ImageDraw, clip: _Clip, frame: int) -> None:
        """The root's path over the last `trail_frames` frames, on the ground, fading with age."""
        start = max(0, frame - self.trail_frames)
        stride = max(1, (frame - start) // 30)  # about 30 segments whatever the frame rate
        picks = np.unique(np.r_[np.arange(start, frame, stride), frame])
        path = clip.root[picks] - clip.root[frame]
        points = self._to_pixels(np.stack([path[:, 0], np.zeros(len(path)), path[:, 1]], axis=-1))
        age = (frame - picks) / self.trail_frames  # 0 now, 1 at the far end of the trail
        for k in range(len(points) - 1):
            shade = min(TRAIL_SHADES - 1, int((1 - age[k + 1]) * TRAIL_SHADES))
            draw.line(
                [tuple(points[k]), tuple(points[k + 1])], fill=clip.trail_inks[shade], width=self.line_width
            )

    def _to_pixels(self, points: np.ndarray) -> np.ndarray:
        """Root-relative world points (..., 3), Y above the clip's lowest point, to panel pixels (..., 2)."""
        right, up, _ = _project(points)
        return np.stack([self.origin[0] + right * self.scale, self.origin[1] - up * self.scale], axis=-1)
