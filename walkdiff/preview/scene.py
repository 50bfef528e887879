"""How a preview is drawn: the camera, the colours, and a `Scene` that frames clips and draws them.

One orthographic camera, turned YAW about the vertical and looking down PITCH (the axis convention of
`walkdiff.preview.render`), sees every clip at one common scale. A `Scene` works out that scale and a
palette once, then draws panels: the ground grid (one periodic image cropped per frame), the requested
path, the ruler, the root's fading trail, contact marks, the facing arrow, the bodies, and the legend
under the panels. `Marks` says which of these a preview wants.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.mirror import name_pairs
from walkdiff.motion.profile import ContactSpec, SkeletonProfile
from walkdiff.motion.representation import contact_state

Color = tuple[int, int, int]

YAW = math.radians(35.0)  # camera azimuth from +Z towards +X: clips walking along X are seen mostly side-on
PITCH = math.radians(18.0)  # camera elevation, enough to see the ground grid and the trail
TRAIL_SHADES = 6  # palette entries per fading trail

BACKGROUND: Color = (250, 250, 247)
GRID: Color = (222, 222, 216)
TEXT: Color = (40, 40, 40)
BODY: Color = (55, 55, 55)
LEFT: Color = (33, 102, 172)
RIGHT: Color = (214, 96, 39)
PLANTED: Color = (26, 152, 80)  # a foot on the ground and still
FACING: Color = (118, 42, 131)
PATH: Color = (0, 160, 160)  # the requested path of `walkdiff walk`
RULER: Color = (70, 70, 70)
FACING_LENGTH = 0.3  # body heights
REACH = 3.0  # body heights either side of a panel's centre, at most: a still of ~4 s of walking


@dataclass(frozen=True)
class Marks:
    """What a preview draws besides bodies, grid and trail (nothing by default).

    feet: joints marked with a green dot on the ground under them while planted: within the contact
        height of the joint's own floor and slower than the contact speed (the rule of the features'
        contact labels, `walkdiff.motion.representation.contact_state`).
    contact: those thresholds (a `ContactSpec`; `feet` says which joints).
    metres_per_unit: a ruler in metres on each panel, and grid lines a round number of metres apart.
    facing: an arrow on the ground from the root along where the body faces, up x (right - left) of the
        left/right joint pair nearest the root (the hips); needs joint names.
    legend: a strip under the panels saying what each colour and mark means (and the clock).
    """

    feet: tuple[int, ...] = ()
    contact: ContactSpec | None = None
    metres_per_unit: float | None = None
    facing: bool = False
    legend: bool = False

    @classmethod
    def of(cls, profile: SkeletonProfile, legend: bool = True) -> Marks:
        """Every mark the profile allows, for clips on its canonical skeleton: contact marks where it has
        feet, the facing arrow where it has left/right pairs, the ruler in its units."""
        spec = profile.contacts if profile.feet else None
        skeleton = profile.canonical_skeleton
        feet = () if spec is None else tuple(skeleton.index(name) for name in spec.joints)
        return cls(feet, spec, profile.metres_per_unit, facing=profile.can_mirror, legend=legend)


NO_MARKS = Marks()


def limb_sides(names: Sequence[str]) -> list[Color | None]:
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


def facing_directions(positions: np.ndarray, parents: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """(F, 2) unit ground directions (x, z) the body faces: up x (right hip - left hip), the hips being
    the left/right joint pair nearest the root that lies apart (CMU's hip joints sit on the root; else
    the pair furthest apart). NaN where the pair coincides on the ground: no facing to show there."""

    def depth(j: int) -> int:
        return 0 if parents[j] < 0 else 1 + depth(int(parents[j]))

    stature = float(np.ptp(positions[..., 1]))
    pairs = sorted(name_pairs(names), key=lambda pair: (depth(pair[0]), pair))
    across = [positions[:, right] - positions[:, left] for left, right in pairs]
    apart = [float(np.median(np.hypot(a[:, 0], a[:, 2]))) for a in across]
    chosen = next((a for a, d in zip(across, apart, strict=True) if d > 0.03 * stature), None)
    if chosen is None:
        chosen = across[int(np.argmax(apart))]
    facing = np.stack([chosen[:, 2], -chosen[:, 0]], axis=-1)  # (0, 1, 0) x across, on the ground
    length = np.linalg.norm(facing, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 1e-9 * max(stature, 1e-9), facing / length, np.nan)


@dataclass
class _Clip:
    xy: np.ndarray  # (F, J, 2) joint pixels in the clip's panel
    depth: np.ndarray  # (F, J) towards the camera: far bones are drawn first
    root: np.ndarray  # (F, 2) the root's world x, z
    anchor: np.ndarray  # (F, 2) the world x, z the camera looks at: the root, or one fixed point
    inks: list[list[int]]  # per shade (faint to full), palette index of the bone ending at each joint
    trail_inks: list[int]  # from faint (oldest) to full
    feet: np.ndarray | None  # (F, n, 3) world positions of the marked joints
    contact: np.ndarray | None  # (F, n) planted
    facing: np.ndarray | None  # (F, 2) ground direction the body faces
    path: np.ndarray | None  # (N, 2) requested path (x, z)


class Scene:
    """Camera framing, palette and drawing shared by every clip, so that all clips have one scale.

    follow: the camera follows each clip's root (animations); else it frames the whole clip (stills).
    """

    def __init__(
        self,
        clips: list[np.ndarray],
        parents: np.ndarray,
        names: Sequence[str] | None,
        colors: Sequence[Color] | None,
        size: tuple[int, int],
        trail_frames: int,
        marks: Marks = NO_MARKS,
        fps: float = 30.0,
        paths: Sequence[np.ndarray | None] | None = None,
        follow: bool = True,
        shades: int = 1,
    ):
        self.parents = parents
        self.size = size
        self.trail_frames = trail_frames
        self.marks = marks
        self.has_names = names is not None
        self.has_paths = paths is not None and any(p is not None for p in paths)
        width, height = size
        self.font = ImageFont.load_default(size=max(9, min(15, round(height / 18))))
        self.legend_font = ImageFont.load_default(size=13)
        self.line_width = max(2, round(height / 110))
        heads = [j for j, n in enumerate(names or []) if n.lower() == "head"]
        self.head = heads[0] if heads else None
        paths = list(paths) if paths is not None else [None] * len(clips)

        # Each clip is seen from above its own root (or the middle of its path) horizontally and its own
        # lowest point vertically.
        relative, anchors = [], []
        for clip, path in zip(clips, paths, strict=True):
            floor = float(clip[..., 1].min())
            if follow:
                anchor = clip[:, 0, [0, 2]]
            else:
                ground = clip[:, 0, [0, 2]] if path is None else np.concatenate([clip[:, 0, [0, 2]], path])
                anchor = np.repeat(((ground.min(0) + ground.max(0)) / 2)[None], len(clip), axis=0)
            anchors.append(anchor)
            relative.append(
                clip - np.stack([anchor[:, 0], np.full(len(clip), floor), anchor[:, 1]], -1)[:, None]
            )
        screen = [_project(r) for r in relative]
        # The body height: each clip's median over its frames of the height its joints span (bounded by its
        # bones), so that a clip flying off (an untrained model's) does not shrink every other one to a dot.
        stature = max(max(float(np.median(np.ptp(clip[..., 1], axis=1))) for clip in clips), 1e-9)
        self.stature = stature
        self.head_radius = 0.055 * stature  # world units until the scale is known
        reach = max(float(np.abs(right).max()) for right, _, _ in screen)
        highest = max(float(up.max()) for _, up, _ in screen) + (1.8 * self.head_radius if heads else 0.0)
        lowest = min(0.0, *(float(up.min()) for _, up, _ in screen))
        if not follow:  # the whole requested path in view too
            for path, anchor in zip(paths, anchors, strict=True):
                if path is not None:
                    flat = np.stack(
                        [path[:, 0] - anchor[0, 0], 0 * path[:, 0], path[:, 1] - anchor[0, 1]], -1
                    )
                    right, up, _ = _project(flat)
                    reach = max(reach, float(np.abs(right).max()))
                    highest, lowest = max(highest, float(up.max())), min(lowest, float(up.min()))
        # Framing for bodies (and walks of a few seconds); what lies further out is cut at the panel's edge.
        reach = min(reach, REACH * stature)
        highest, lowest = min(highest, 1.4 * stature), max(lowest, -stature)
        # Room for the title above and for some ground (grid, trail, ruler) below the feet.
        top, bottom, side = 1.6 * self.font.size, 0.14 * height, 0.05 * width
        self.scale = min((width / 2 - side) / max(reach, 1e-9), (height - top - bottom) / (highest - lowest))
        spare = (height - top - bottom) - (highest - lowest) * self.scale  # when the width limits the scale
        self.origin = np.array(
            [width / 2, top + spare / 2 + highest * self.scale]
        )  # the ground below the root
        self.head_radius *= self.scale

        self.palette: dict[Color, int] = {BACKGROUND: 0}  # index 0: new images start as background
        self.grid_ink = self.ink(GRID)
        self.text_ink = self.ink(TEXT)
        self.planted_ink = self.ink(PLANTED)
        self.facing_ink = self.ink(FACING)
        self.path_ink = self.ink(PATH)
        self.ruler_ink = self.ink(RULER)
        self.sides = [None] * len(parents) if names is None else limb_sides(names)
        self.clips = []
        for i, (clip, rel, (_, _, depth)) in enumerate(zip(clips, relative, screen, strict=True)):
            body = BODY if colors is None else tuple(int(c) for c in colors[i])
            feet = contact = None
            if marks.feet:
                feet = clip[:, list(marks.feet)]
                low, slow = contact_state(feet, fps, marks.contact)
                contact = low & slow
            self.clips.append(
                _Clip(
                    xy=self._to_pixels(rel),
                    depth=depth,
                    root=clip[:, 0, [0, 2]],
                    anchor=anchors[i],
                    inks=[
                        [self.ink(_mix(s or body, 0.25 + 0.75 * (k + 1) / shades)) for s in self.sides]
                        for k in range(shades)
                    ],
                    trail_inks=[
                        self.ink(_mix(body, (k + 1) / (TRAIL_SHADES + 1))) for k in range(TRAIL_SHADES)
                    ],
                    feet=feet,
                    contact=contact,
                    facing=facing_directions(clip, parents, names) if marks.facing else None,
                    path=None if paths[i] is None else np.asarray(paths[i], dtype=np.float64),
                )
            )
        unit = marks.metres_per_unit
        # Grid lines a round number of metres apart when the units are known.
        metres = 1.0 if unit is None else unit
        step = _nice_step(stature * metres / (2 if unit is None else 3))
        while step / metres * self.scale * math.sin(PITCH) < 6:  # lines far enough apart to read as a grid
            step = _nice_step(2.2 * step)
        self.grid_step = step / metres
        self.grid = self._grid_image()

    def ink(self, color: Color) -> int:
        """Palette index of a colour, added on first use (only while setting up, before any image exists)."""
        if color not in self.palette:
            if len(self.palette) == 256:
                raise WalkdiffError("too many clip colours for one palette (at most about 30 clips)")
            self.palette[color] = len(self.palette)
        return self.palette[color]

    # ------------------------------------------------------------ layout

    def place(self, index: int, columns: int | None) -> tuple[int, int]:
        """Top-left pixel of panel `index` in a grid of `columns` (one row when None)."""
        columns = columns or len(self.clips)
        return (index % columns) * self.size[0], (index // columns) * self.size[1]

    def canvas(self, panels: int, columns: int | None, clock: str | None = None) -> Image.Image:
        """A background image for `panels` panels in rows of `columns`, with the legend below them."""
        columns = min(columns or panels, panels)
        rows = math.ceil(panels / columns)
        width, height = columns * self.size[0], rows * self.size[1]
        if not self.marks.legend:
            return self._blank((width, height))
        lines = self._legend_lines(width, clock)
        step = self.legend_font.size + 8
        image = self._blank((width, height + step * len(lines) + 6))
        draw = ImageDraw.Draw(image)
        for k, items in enumerate(lines):
            self._legend_line(draw, items, height + 6 + k * step, step)
        return image

    def _legend_items(self) -> list[tuple[str, str, int]]:
        """(glyph, text, ink) of each mark drawn: glyphs 'line', 'dot', 'arrow', 'ruler'."""
        items = []
        if self.has_names:
            items += [("line", "left limbs", self.ink(LEFT)), ("line", "right limbs", self.ink(RIGHT))]
        if self.marks.feet:
            items.append(("dot", "foot planted", self.planted_ink))
        if self.marks.facing:
            items.append(("arrow", "facing", self.facing_ink))
        if self.has_paths:
            items.append(("line", "requested path", self.path_ink))
        if self.trail_frames:
            items.append(("line", "root path", self.clips[0].trail_inks[-1]))
        if self.marks.metres_per_unit is not None:
            metres = self.grid_step * self.marks.metres_per_unit
            items.append(("ruler", f"ruler 1 m, ticks and grid {metres:g} m", self.ruler_ink))
        return items

    def _legend_lines(self, width: int, clock: str | None) -> list[list[tuple[str, str, int]]]:
        lines, used = [[]], 0
        for item in ([("text", clock, self.text_ink)] if clock else []) + self._legend_items():
            need = (0 if item[0] == "text" else 34) + self.legend_font.getlength(item[1]) + 16
            if used + need > width - 8 and lines[-1]:
                lines.append([])
                used = 0
            lines[-1].append(item)
            used += need
        return lines

    def _legend_line(self, draw: ImageDraw.ImageDraw, items, y: float, step: float) -> None:
        x, middle = 8.0, y + step / 2
        for glyph, text, ink in items:
            if glyph == "dot":
                draw.ellipse([(x + 8, middle - 5), (x + 18, middle + 5)], fill=ink)
            elif glyph == "text":
                pass
            elif glyph == "ruler":
                draw.line([(x, middle + 3), (x + 26, middle + 3)], fill=ink, width=2)
                for tick in (x, x + 13, x + 26):
                    draw.line([(tick, middle - 2), (tick, middle + 3)], fill=ink, width=1)
            else:
                draw.line([(x, middle), (x + 26, middle)], fill=ink, width=3)
                if glyph == "arrow":
                    draw.polygon([(x + 28, middle), (x + 20, middle - 5), (x + 20, middle + 5)], fill=ink)
            indent = 0 if glyph == "text" else 34
            draw.text((x + indent, middle), text, fill=self.text_ink, font=self.legend_font, anchor="lm")
            x += indent + self.legend_font.getlength(text) + 16

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

    # ------------------------------------------------------------ drawing

    def _ground(self, clip: _Clip, frame: int) -> tuple[Image.Image, ImageDraw.ImageDraw]:
        """The panel's grid seen from the clip's anchor at `frame`, with the requested path and ruler."""
        cell = np.mod(clip.anchor[frame], self.grid_step)
        shift = (
            np.round(self._to_pixels(np.array([cell[0], 0.0, cell[1]])) - self.origin).astype(int)
            + self.margin
        )
        image = self.grid.crop((shift[0], shift[1], shift[0] + self.size[0], shift[1] + self.size[1]))
        draw = ImageDraw.Draw(image)
        if clip.path is not None:
            points = self._ground_pixels(clip.path - clip.anchor[frame])
            draw.line(
                [tuple(p) for p in points], fill=self.path_ink, width=self.line_width + 1, joint="curve"
            )
            for end, radius in ((points[0], 1.6), (points[-1], 2.4)):  # start small, end large
                r = radius * self.line_width
                draw.ellipse([tuple(end - r), tuple(end + r)], outline=self.path_ink, width=2)
        if self.marks.metres_per_unit is not None:
            self._draw_ruler(draw)
        return image, draw

    def _draw_ruler(self, draw: ImageDraw.ImageDraw) -> None:
        """1 m along the screen's horizontal in the bottom-left corner, ticked at the grid spacing.

        The camera is orthographic and its horizontal axis lies on the ground, so horizontal lengths on
        screen are true lengths on the ground, at the panel's scale.
        """
        per_metre = self.scale / self.marks.metres_per_unit
        tick = self.grid_step * self.scale
        length = per_metre  # 1 m
        x0, y = 8.0, self.size[1] - 8.0
        draw.line([(x0, y), (x0 + length, y)], fill=self.ruler_ink, width=2)
        for k in range(round(length / tick) + 1):
            x = x0 + k * tick
            draw.line([(x, y - (6 if k in (0, round(length / tick)) else 3)), (x, y)], fill=self.ruler_ink)
        draw.text((x0 + length + 4, y), "1 m", fill=self.ruler_ink, font=self.font, anchor="ls")

    def _draw_contacts(self, draw: ImageDraw.ImageDraw, clip: _Clip, frame: int, anchor: np.ndarray) -> None:
        """A flat dot on the ground under each marked joint planted at `frame`."""
        radius = max(3.0, 0.025 * self.stature * self.scale)
        for planted, foot in zip(clip.contact[frame], clip.feet[frame], strict=True):
            if planted:
                x, y = self._ground_pixels(foot[None, [0, 2]] - anchor)[0]
                box = [(x - radius, y - radius * 0.6), (x + radius, y + radius * 0.6)]
                draw.ellipse(box, fill=self.planted_ink)

    def _draw_facing(self, draw: ImageDraw.ImageDraw, clip: _Clip, frame: int, anchor: np.ndarray) -> None:
        """An arrow on the ground from the root along where the body faces at `frame` (none where the
        hips coincide)."""
        if not np.isfinite(clip.facing[frame]).all():
            return
        root = clip.root[frame]
        tip = root + clip.facing[frame] * FACING_LENGTH * self.stature
        start, end = self._ground_pixels(np.stack([root, tip]) - anchor)
        draw.line([tuple(start), tuple(end)], fill=self.facing_ink, width=self.line_width + 1)
        direction = (end - start) / max(float(np.hypot(*(end - start))), 1e-9)
        normal = np.array([-direction[1], direction[0]]) * 0.6
        head = 3.0 * self.line_width + 3
        tips = [
            end + direction * head * 0.6,
            end - (direction - normal) * head,
            end - (direction + normal) * head,
        ]
        draw.polygon([tuple(p) for p in tips], fill=self.facing_ink)

    def _draw_body(self, draw: ImageDraw.ImageDraw, clip: _Clip, frame: int, inks: list[int]) -> None:
        joints = clip.xy[frame]
        depth = clip.depth[frame]
        for j in sorted(range(1, len(self.parents)), key=lambda j: depth[j] + depth[self.parents[j]]):
            draw.line([tuple(joints[self.parents[j]]), tuple(joints[j])], fill=inks[j], width=self.line_width)
        if self.head is not None:
            # The head joint sits at the base of the skull: put the circle a little further along the neck.
            up = joints[self.head] - joints[max(self.parents[self.head], 0)]
            centre = joints[self.head] + up / max(float(np.hypot(*up)), 1e-9) * self.head_radius * 0.8
            box = [tuple(centre - self.head_radius), tuple(centre + self.head_radius)]
            draw.ellipse(box, fill=0, outline=inks[self.head], width=self.line_width)

    def _finish(self, draw: ImageDraw.ImageDraw, title: str | None) -> None:
        if title:
            draw.text((self.size[0] / 2, 3), title, fill=self.text_ink, font=self.font, anchor="ma")
        draw.rectangle([(0, 0), (self.size[0] - 1, self.size[1] - 1)], outline=self.grid_ink)

    def panel(self, index: int, frame: int, title: str | None) -> Image.Image:
        """Clip `index` at `frame` (its last frame if shorter) on its own panel, so nothing spills over."""
        clip = self.clips[index]
        frame = min(frame, len(clip.xy) - 1)
        image, draw = self._ground(clip, frame)
        if self.trail_frames and frame:
            self._draw_trail(draw, clip, frame, max(0, frame - self.trail_frames))
        if clip.contact is not None:
            self._draw_contacts(draw, clip, frame, clip.anchor[frame])
        if clip.facing is not None:
            self._draw_facing(draw, clip, frame, clip.anchor[frame])
        self._draw_body(draw, clip, frame, clip.inks[-1])
        self._finish(draw, title)
        return image

    def strobe(self, index: int, poses: int, title: str | None) -> Image.Image:
        """Clip `index` as `poses` poses from its first frame to its last on one fixed view, older ones
        fainter, over its whole root path and every contact mark of the clip."""
        clip = self.clips[index]
        last = len(clip.xy) - 1
        image, draw = self._ground(clip, 0)
        if last:
            self._draw_trail(draw, clip, last, 0)
        if clip.contact is not None:  # footprints: every contact of the clip
            for frame in range(last + 1):
                self._draw_contacts(draw, clip, frame, clip.anchor[0])
        picks = np.linspace(0, last, poses).round().astype(int)
        if clip.facing is not None:  # where the body faces at the end (the strongest pose)
            self._draw_facing(draw, clip, last, clip.anchor[0])
        for k, frame in enumerate(picks):
            self._draw_body(draw, clip, int(frame), clip.inks[k * len(clip.inks) // poses])
        self._finish(draw, title)
        return image

    def _draw_trail(self, draw: ImageDraw.ImageDraw, clip: _Clip, frame: int, start: int) -> None:
        """The root's path from `start` to `frame`, on the ground, fading with age."""
        stride = max(1, (frame - start) // 60)  # about 60 segments whatever the frame rate
        picks = np.unique(np.r_[np.arange(start, frame, stride), frame])
        points = self._ground_pixels(clip.root[picks] - clip.anchor[frame])
        age = (frame - picks) / max(frame - start, 1)  # 0 now, 1 at the far end of the trail
        for k in range(len(points) - 1):
            shade = min(TRAIL_SHADES - 1, int((1 - age[k + 1]) * TRAIL_SHADES))
            draw.line(
                [tuple(points[k]), tuple(points[k + 1])], fill=clip.trail_inks[shade], width=self.line_width
            )

    def _ground_pixels(self, xz: np.ndarray) -> np.ndarray:
        """Ground points (N, 2) relative to the anchor -> panel pixels (N, 2)."""
        return self._to_pixels(np.stack([xz[:, 0], np.zeros(len(xz)), xz[:, 1]], axis=-1))

    def _to_pixels(self, points: np.ndarray) -> np.ndarray:
        """Anchor-relative world points (..., 3), Y above the clip's lowest point -> panel pixels (..., 2)."""
        right, up, _ = _project(points)
        return np.stack([self.origin[0] + right * self.scale, self.origin[1] - up * self.scale], axis=-1)
