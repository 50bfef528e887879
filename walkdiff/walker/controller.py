"""Live control of a path walker: a direction, a speed and a style in per character, a pose out per frame.

    controller = walkdiff.load("checkpoints/walk_xia/last.ckpt").controller(style="old")
    pose = controller.step(direction=(1, 0), speed=1.2)   # a frame, walking towards +x at 1.2 m/s

The `PathWalker` was trained with a control that says where the walker goes next: K points 0, e, 2e, ..
frames ahead (at arc lengths `pace(speed)`) in its own frame. A `WalkController` builds that control from
the command instead of from a path, every frame, from where the walker is:

- **Straight**: the points lie on the ray from the current root along the commanded direction, at the
  commanded pace. The direction is a world direction, so the control re-aims every frame at it from
  wherever the walker has got to: the heading's sway over a stride does not make the walk drift.
- **Turning**: the points bend from the current heading towards the commanded direction at `turn_rate`
  (default 720 degrees/s), then run straight along it: an arc of radius speed / turn_rate, a tight
  corner that starts straight ahead. The walker turns more slowly than its control bends (Xia's walks
  turn gently), so the control bends sharply to get a quick turn out of it (docs/live-control.md has
  the figures). A command further round
  than 90 degrees is aimed at as a 90 degree turn, renewed every frame as the walker turns, so the points
  never lie behind the walker (which would ask it to back up, what it has hardly seen). A command
  exactly behind turns left. `turn_rate=math.inf`: no bend.
- **Stop**: speed 0 puts every point at the root, the control of a walker standing still; it slows to a
  stand and stays there. Without pace the points have no direction: it turns again once it walks.
- **Heading assist**: each frame's root is turned a little further towards the commanded direction, at
  most `heading_assist` degrees/s (`assist`); **foot lock**: planted feet held where they landed
  (`foot_lock.FootLock`), and free feet that skim the floor lifted clear of it. Both change only the
  frame shown and kept, never what the walker feeds back.
- **Speed and style** act on the next frame: the pace at once, the style embedding (a name, a mix
  'angry:0.7,old:0.3' or mixing weights) and example clips ramped, eased in and out, over `transition`
  seconds (`TRANSITION`; 0: at once, which a walker whose denoiser reads the style itself shows as a
  jolt). With no speed given the walker walks at the style's own mean speed in the training data (mixed
  as the styles are), following the style as it changes.

N characters (`characters=N`) are N rows of one batch: one network pass a frame for all. They share one
random generator, so a character's motion depends on the seed and N, never on the other characters'
commands; a batch's row is not the same sample as a single controller of that seed.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.path_walker import advance_root
from walkdiff.models.pipeline import Pipeline
from walkdiff.models.style_examples import MATCH_CLIPS, clip_statistics, clips_record
from walkdiff.models.style_labels import eased, parse_style
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.kinematics import forward_kinematics
from walkdiff.motion.representation import decode
from walkdiff.motion.rotations import matrix_to_quaternion, sixd_to_matrix
from walkdiff.motion.skeleton import Motion
from walkdiff.retarget.take import Take
from walkdiff.walker.foot_lock import FootLock

TRANSITION = 0.5  # seconds a style change is ramped over (live-control.md: seams at style switches)
TURN_RATE = 720.0  # degrees per second the control's path bends at towards a new direction
MAX_AIM = math.pi / 2  # the control never aims further off the heading than this (no walking backwards)
HEADING_ASSIST = 45.0  # degrees per second the root may be turned beyond the walker's own turn
ASSIST_TIME = 0.25  # seconds: the time constant of that correction
DEFAULT_SAMPLER = SamplerChoice("ddim", 10, 1.0)  # 7.9 ms a frame on 2 cores, lock included (live-control.md)


@dataclass(frozen=True)
class Pose:
    """One frame of one character.

    `positions`: world positions (J, 3) of the training skeleton's joints, in metres, Y up (walkdiff's
    axes); `rotations`: their local rotations as unit quaternions [x, y, z, w] on that skeleton's own
    axes (what its BVH holds); `root`: the root joint's world position (3,) in metres, Y up; `heading`:
    the root's facing in degrees (0: towards +z, 90: towards +x); `translation`: the first joint's
    translation in the BVH's units and axes (what `walk --stream` prints as "root").
    """

    frame: int
    character: int
    positions: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    heading: float
    translation: np.ndarray


@dataclass(frozen=True)
class Ramp:
    """A change ramped over `frames` frames (eased: `share`), `done` of them made: style weights, or
    example clips' statistics."""

    start: object
    end: object
    done: int = 0
    frames: int = 0

    @property
    def share(self) -> float:
        """How far along the next frame is (1: arrived), eased in and out (`eased`)."""
        return 1.0 if self.done >= self.frames else eased((self.done + 1) / self.frames)

    def next(self) -> Ramp:
        return replace(self, done=min(self.done + 1, self.frames))


def angle_of(direction, what: str = "direction") -> float:
    """A direction on the ground as its heading angle in radians: a number is an angle in degrees (0:
    +z, 90: +x), a pair (x, z) a vector."""
    if isinstance(direction, int | float | np.floating | np.integer) and not isinstance(direction, bool):
        if not math.isfinite(direction):
            raise WalkdiffError(f"{what}: expected an angle in degrees, got {direction}")
        return math.radians(float(direction))
    try:
        x, z = (float(v) for v in direction)
    except (TypeError, ValueError):
        raise WalkdiffError(f"{what}: expected [x, z] or an angle in degrees, got {direction!r}") from None
    if not (math.isfinite(x) and math.isfinite(z)) or x == z == 0:
        raise WalkdiffError(
            f"{what}: expected a non-zero [x, z] of finite numbers (speed 0 stops), got {[x, z]}"
        )
    return math.atan2(x, z)


def checked_speed(speed, what: str = "speed") -> float:
    if isinstance(speed, bool) or not isinstance(speed, int | float | np.floating | np.integer):
        raise WalkdiffError(f"{what}: expected metres per second (a number >= 0), got {speed!r}")
    if not (math.isfinite(speed) and speed >= 0):
        raise WalkdiffError(f"{what}: expected metres per second (a number >= 0), got {speed}")
    return float(speed)


def command_control(
    heading: np.ndarray, target: np.ndarray, speed: np.ndarray, times: np.ndarray, turn_rate: float
) -> np.ndarray:
    """The raw controls (N, 2K) of walkers facing `heading` (N,) told to walk towards `target` (N,) (both
    radians) at `speed` (N,) units/s: K points `times` (K,) seconds ahead along an arc that turns from the
    heading to the target (at most a quarter turn away: `MAX_AIM`) at `turn_rate` rad/s, then straight
    on, as (x, z) in each walker's own frame."""
    delta = np.remainder(target - heading + math.pi, 2 * math.pi) - math.pi  # [-pi, pi)
    delta = np.where(delta == -math.pi, math.pi, delta)  # straight behind: turn left
    delta = np.clip(delta, -MAX_AIM, MAX_AIM)  # further round: a quarter turn, renewed as the walker turns
    side, size = np.sign(delta)[:, None], np.abs(delta)[:, None]
    v, t = speed[:, None], times[None, :]
    if math.isinf(turn_rate):
        bend = np.zeros_like(size)
        x, z = v * t * np.sin(delta)[:, None], v * t * np.cos(delta)[:, None]
    else:
        bend = np.minimum(t, size / turn_rate)  # time spent turning before each point
        radius = v / turn_rate
        x = side * radius * (1 - np.cos(turn_rate * bend))
        z = radius * np.sin(turn_rate * bend)
        straight = v * (t - bend)
        x, z = x + straight * np.sin(side * size), z + straight * np.cos(size)
    return np.stack([x, z], axis=-1).reshape(len(heading), -1)


def style_weights(model, style) -> tuple[torch.Tensor, str]:
    """Mixing weights (S,) over the model's styles and a label, from a name, a mix 'angry:0.7,old:0.3',
    or weights (a sequence or tensor of S numbers >= 0, not all 0)."""
    count = len(model.spec["styles"])
    if isinstance(style, str):
        value, label = parse_style(model, style)
        if not value.is_floating_point():
            value = torch.nn.functional.one_hot(value, count)
        return value.double().cpu(), label
    weights = torch.as_tensor(np.asarray(style, dtype=np.float64)).flatten()
    if (
        weights.shape != (count,)
        or not torch.isfinite(weights).all()
        or (weights < 0).any()
        or weights.sum() <= 0
    ):
        raise WalkdiffError(
            f"style: expected a name, a mix 'angry:0.7,old:0.3' or {count} weights >= 0 (not all 0), "
            f"got {style!r}"
        )
    weights = weights / weights.sum()
    names = model.spec["styles"]
    label = "+".join(f"{names[i]}{round(100 * float(w))}" for i, w in enumerate(weights) if w > 0)
    return weights, label


def yaw(heading: np.ndarray) -> np.ndarray:
    """(N,) angles -> (N, 3, 3) rotations about +Y, turning +Z to (sin h, 0, cos h) (`yaw_matrix`)."""
    sin, cos, zero, one = np.sin(heading), np.cos(heading), np.zeros_like(heading), np.ones_like(heading)
    return np.stack([cos, zero, sin, zero, one, zero, -sin, zero, cos], -1).reshape(-1, 3, 3)


class WalkController:
    """A `PathWalker` driven a frame at a time by commands; see the module docstring.

    `style`: where each character starts (name, mix or weights); `speed`: m/s (None: the style's own);
    `positions` (N, 2) in metres and `headings` (N,) in degrees: where the characters start (default: the
    origin, facing +z). `record`: keep the frames for `take` (False: keep nothing, for endless use).
    `style_clips`: example clips ('a.bvh:0.7,b.bvh', paths, Motions or (clip, weight) pairs) whose pose
    statistics every character takes on as well, at `match_clips` (`RunningMatch`; docs/walking.md).
    """

    def __init__(
        self,
        model,
        style,
        speed: float | None = None,
        seed: int = 0,
        sampler: SamplerChoice | None = None,
        characters: int = 1,
        transition: float = TRANSITION,
        turn_rate: float = TURN_RATE,
        heading_assist: float = HEADING_ASSIST,
        foot_lock: bool = True,
        positions=None,
        headings=None,
        record: bool = True,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
    ):
        if not (isinstance(characters, int) and characters >= 1):
            raise WalkdiffError(f"characters: expected a whole number >= 1, got {characters!r}")
        if not (math.isfinite(transition) and transition >= 0):
            raise WalkdiffError(f"transition: expected seconds >= 0, got {transition}")
        if not turn_rate > 0:
            raise WalkdiffError(f"turn_rate: expected degrees per second > 0, got {turn_rate}")
        self.model = model.eval()
        self.characters, self.transition, self.record = characters, float(transition), bool(record)
        if not (math.isfinite(heading_assist) and heading_assist >= 0):
            raise WalkdiffError(f"heading_assist: expected degrees per second >= 0, got {heading_assist}")
        self.turn_rate = math.radians(turn_rate)
        self.heading_assist = math.radians(heading_assist)
        self.unit = model.profile.metres_per_unit
        profile = model.profile  # what every frame's poses need, worked out once
        self.skeleton, self.root = model.skeleton, profile.skeleton.index(profile.root)
        self.turn = profile.turn.T * self.unit  # file axes and units -> metres, Y up
        self.times = np.asarray(model.ahead, dtype=np.float64) / self.fps
        self.sampler = sampler or DEFAULT_SAMPLER
        self.generator = torch.Generator(device=model.device).manual_seed(seed)
        self.streams = model.start_streams(characters, self.sampler)
        self.position = np.zeros((characters, 2)) if positions is None else self._positions(positions)
        self.heading = np.zeros(characters) if headings is None else self._headings(headings)
        self.target = self.heading.copy()  # the commanded direction of travel (radians)
        self.assisted = np.zeros(characters)  # radians each root was turned by the assist, in all
        self.lock = FootLock(model, characters) if foot_lock else None
        self.speed: list[float | None] = [None] * characters  # m/s; None: the style's own
        weights, label = style_weights(model, style)
        self.weights = weights[None].repeat(characters, 1)  # the conditioning now (N, S)
        self.ramp = [Ramp(weights, weights)] * characters
        self.labels = [label] * characters
        # As given: what manifests record and the keys start from.
        self.start_style, self.start_speed, self.seed, self.style_clips = style, speed, seed, style_clips
        self.match_clips, self.guide = match_clips, None
        self.clip_cache: dict[str, StyleStatistics | None] = {}  # clips given as text, read once (the C key)
        self.matching: list[Ramp] = []  # example clips' statistics per character, once any are given
        self.matched: list[StyleStatistics] = []  # ... and those of the last frame
        self.clips: list[list[dict]] = [[] for _ in range(characters)]  # each character's clips, as recorded
        if style_clips:
            self.command(style_clips=style_clips)
            self.matching = [Ramp(r.end, r.end) for r in self.matching]  # from the first frame, no ramp
        self.start_clips = self.clips[0]  # what the characters started with (manifests)
        self.frame = 0
        # Per frame kept for `take`: the frame, its raw features (N, D), the root (N, 2) and heading (N,).
        self.kept: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        for k in range(characters):
            self.command(speed=speed, character=k)

    # ------------------------------------------------------------ what it is

    @property
    def fps(self) -> float:
        return self.model.spec["fps"]

    @property
    def styles(self) -> tuple[str, ...]:
        return tuple(self.model.spec["styles"])

    @property
    def joints(self) -> list[str]:
        """The training skeleton's joints, in the order of a Pose's positions and rotations."""
        return list(self.model.profile.skeleton.names)

    def style_speed(self, weights: torch.Tensor) -> float:
        """The mean walking speed (m/s) of a style's weights in the training data (0: none known)."""
        return float(weights.double() @ self.model.style_speed.double().cpu()) * self.unit

    def speed_of(self, style) -> float:
        """The style's own mean walking speed in m/s (a name, a mix or weights)."""
        return self.style_speed(style_weights(self.model, style)[0])

    def commanded(self, character: int = 0) -> dict:
        """The command a character follows: direction (degrees), speed (m/s) and style label."""
        return {
            "direction": round(math.degrees(self.target[character]), 4),
            "speed": round(self._speed(character), 4),
            "style": self.labels[character],
        } | ({"style_clips": self.clips[character]} if self.clips[character] else {})

    # ------------------------------------------------------------ commands

    def command(
        self, direction=None, speed=None, style=None, character: int | None = None, style_clips=None
    ) -> None:
        """Change what `character` (None: every one) does from the next frame on; None keeps a field.
        `direction`: (x, z) or an angle in degrees (0: +z, 90: +x); `speed`: m/s, 0 stops; `style`: a
        name, a mix or weights; `style_clips`: example clips (as the constructor's; "" or []: none),
        ramped in and out as a style is."""
        rows = range(self.characters) if character is None else [self._character(character)]
        angle = None if direction is None else angle_of(direction)
        value = None if speed is None else checked_speed(speed)
        weights = None if style is None else style_weights(self.model, style)
        matched = None if style_clips is None else self._statistics(style_clips)
        for k in rows:  # checked first: a refused command changes nothing
            own = (value if speed is not None else self.speed[k]) is None
            target, label = weights if weights is not None else (self.ramp[k].end, self.labels[k])
            if own and not self.style_speed(target) > 0:
                raise WalkdiffError(
                    f"style {label}: the checkpoint has no walking speed for it; give a speed"
                )
        frames = round(self.transition * self.fps)
        if matched is not None and matched[0] is not None and self.guide is None:
            self._start_matching(matched[0])
        for k in rows:
            if weights is not None:
                self.ramp[k] = Ramp(self.weights[k].clone(), weights[0], 0, frames)
                self.labels[k] = weights[1]
            if matched is not None and self.guide is not None:  # (no clips to drop before the first)
                statistics, self.clips[k] = matched
                dropped = replace(self.matched[k], strength=torch.zeros(()))  # its strength ramps to 0
                self.matching[k] = Ramp(self.matched[k], statistics or dropped, 0, frames)
            if angle is not None:
                self.target[k] = angle
            if value is not None:
                self.speed[k] = value

    def step(self, direction=None, speed=None, style=None) -> Pose | list[Pose]:
        """The next frame, after `command(direction, speed, style)` for every character (None keeps a
        field): a Pose, or with several characters a list of one per character (give each its own
        command with `command(..., character=k)`, then `step()`)."""
        if direction is not None or speed is not None or style is not None:
            self.command(direction, speed, style)
        poses = self.advance()
        return poses[0] if self.characters == 1 else poses

    @torch.inference_mode()
    def advance(self) -> list[Pose]:
        """One frame of every character under its current command: a Pose each."""
        for k, ramp in enumerate(self.ramp):
            self.weights[k] = ramp.start + ramp.share * (ramp.end - ramp.start)
            self.ramp[k] = ramp.next()
        if self.guide is not None:
            self.matched = [ramp.start.towards(ramp.end, ramp.share) for ramp in self.matching]
            self.matching = [ramp.next() for ramp in self.matching]
            self.guide.target = StyleStatistics.stack(self.matched)
        speed = np.array([self._speed(k) for k in range(self.characters)]) / self.unit
        control = command_control(self.heading, self.target, speed, self.times, self.turn_rate)
        model = self.model
        control = torch.from_numpy(control).float().to(model.device)[:, None]
        encoded = model.encode_control(control, self.weights.float().to(model.device))[:, 0]
        x = model.advance(self.streams, encoded, self.generator)
        raw = model.normalizer.denormalize(x).double().cpu().numpy()
        self.assist(raw, speed)
        if self.lock is not None:
            self.lock.apply(raw, self.position, self.heading)
        poses = self.poses(raw, self.position, self.heading)
        if self.record:
            self.kept.append((self.frame, raw, self.position.copy(), self.heading.copy()))
        self.position, self.heading = advance_root(self.position, self.heading, raw, model.layout)
        self.frame += 1
        return poses

    def assist(self, raw: np.ndarray, speed: np.ndarray) -> None:
        """Turns the frames (N, D) of walking characters a little further towards their commanded
        direction: the heading error left after the frame's own turn closes with time constant
        `ASSIST_TIME`, at most `heading_assist` radians a second (what game controllers call root motion
        correction). A standing character is left as it is."""
        if self.heading_assist == 0:
            return
        turn = raw[:, self.model.layout.heading_vel.start]
        error = np.remainder(self.target - (self.heading + turn) + math.pi, 2 * math.pi) - math.pi
        limit = self.heading_assist / self.fps
        extra = np.where(speed > 0, np.clip(error / (ASSIST_TIME * self.fps), -limit, limit), 0.0)
        raw[:, self.model.layout.heading_vel.start] = turn + extra
        self.assisted += np.abs(extra)

    # ------------------------------------------------------------ poses and takes

    def poses(self, raw: np.ndarray, position: np.ndarray, heading: np.ndarray) -> list[Pose]:
        """The Poses of one frame of raw features (N, D) of walkers at `position` (N, 2), `heading` (N,)."""
        profile, skeleton, layout = self.model.profile, self.skeleton, self.model.layout
        sixd = torch.from_numpy(raw[:, layout.rotations]).unflatten(-1, (layout.num_joints, 6))
        rotations = sixd_to_matrix(sixd).numpy()
        rotations[:, 0] = yaw(heading) @ rotations[:, 0]
        translations = np.repeat(skeleton.offsets[None], len(raw), axis=0)
        translations[:, 0] = np.stack([position[:, 0], raw[:, layout.root_height.start], position[:, 1]], -1)
        canonical = Motion(skeleton, rotations, translations, 1.0 / self.fps)
        file = profile.to_file(canonical)  # characters as frames: every frame is converted on its own
        world = forward_kinematics(file.rotations, file.positions, profile.skeleton.parents) @ self.turn
        quaternions = matrix_to_quaternion(torch.from_numpy(file.rotations)).numpy()
        degrees = 180 - np.remainder(180 - np.degrees(heading), 360)  # (-180, 180]
        return [
            Pose(
                self.frame,
                k,
                world[k],
                quaternions[k],
                world[k, self.root],
                float(degrees[k]),
                file.positions[k, 0],
            )
            for k in range(len(raw))
        ]

    @property
    def recorded(self) -> list[int]:
        """The frames kept for `take`."""
        return [frame for frame, *_ in self.kept]

    def take(self, character: int = 0) -> Take:
        """The kept frames of a character as a `Take` on the training files' skeleton (write it with
        `to_bvh` / `to_glb`). Frames left out (record off) are cut: the take's root runs on without a
        jump, the body's pose changes at the cut."""
        k = self._character(character)
        if not self.kept:
            raise WalkdiffError("no frames recorded: step the controller with record on first")
        raw = np.stack([r[k] for _, r, _, _ in self.kept])
        _, _, position, heading = self.kept[0]
        motion = decode(raw, self.model.skeleton, 1.0 / self.fps, position[k], float(heading[k]))
        return Pipeline(self.model).take(motion)

    def fork(self) -> WalkController:
        """An independent copy in the same state: the same frames follow from the same commands."""
        other = copy.copy(self)
        other.generator = torch.Generator(device=self.model.device)
        other.generator.set_state(self.generator.get_state())
        other.streams = copy.copy(self.streams)  # advancing every row replaces its tensors, never writes them
        for name in ("position", "heading", "target", "assisted"):
            setattr(other, name, getattr(self, name).copy())
        other.speed, other.ramp, other.labels = list(self.speed), list(self.ramp), list(self.labels)
        other.weights, other.kept = self.weights.clone(), list(self.kept)
        other.lock = None if self.lock is None else self.lock.copy()
        other.matching, other.matched, other.clips = list(self.matching), list(self.matched), list(self.clips)
        if self.guide is not None:  # its running statistics are the fork's own from here on
            other.streams.tables = copy.copy(self.streams.tables)
            other.guide = other.streams.tables.guide = copy.copy(self.guide)
        return other

    # ------------------------------------------------------------ example clips

    def _statistics(self, style_clips) -> tuple[StyleStatistics | None, list[dict]]:
        """Example clips' statistics (None for none: "" or []) and their record; clips given as text are
        read once (C on the page turns the same clips off and on)."""
        if not (isinstance(style_clips, str) and style_clips in self.clip_cache):
            statistics = clip_statistics(self.model, style_clips, self.match_clips)
            if not isinstance(style_clips, str):
                return statistics, clips_record(style_clips)
            self.clip_cache[style_clips] = statistics
        return self.clip_cache[style_clips], clips_record(style_clips)

    def _start_matching(self, statistics: StyleStatistics) -> None:
        """The first clips given: every frame of every character is matched from now on (a `RunningMatch`),
        each character from strength 0 until its own clips ramp in."""
        off = replace(statistics, strength=torch.zeros(()))
        self.matching, self.matched = [Ramp(off, off)] * self.characters, [off] * self.characters
        self.guide = self.model.match_streams(self.streams, off, self.sampler)

    # ------------------------------------------------------------ checks

    def _speed(self, k: int) -> float:
        """Character k's speed now in m/s: the commanded one, or its style's own as the style is now."""
        return self.speed[k] if self.speed[k] is not None else self.style_speed(self.weights[k])

    def _character(self, character) -> int:
        if not (isinstance(character, int) and 0 <= character < self.characters):
            raise WalkdiffError(f"character: expected 0 to {self.characters - 1}, got {character!r}")
        return character

    def _positions(self, positions) -> np.ndarray:
        array = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        if array.shape != (self.characters, 2) or not np.isfinite(array).all():
            raise WalkdiffError(f"positions: expected {self.characters} finite (x, z) pairs in metres")
        return array / self.unit

    def _headings(self, headings) -> np.ndarray:
        array = np.radians(np.asarray(headings, dtype=np.float64).reshape(-1))
        if array.shape != (self.characters,) or not np.isfinite(array).all():
            raise WalkdiffError(f"headings: expected {self.characters} finite angles in degrees")
        return array


def first_style(model) -> str:
    """The model's first style with a known walking speed: what a walker starts as by default."""
    styles, speeds = model.spec["styles"], model.style_speed.cpu().numpy()
    return next((s for s, v in zip(styles, speeds, strict=True) if v > 0), styles[0])


def controller(
    model,
    style=None,
    speed=None,
    seed=0,
    sampler="ddim",
    steps=None,
    eta=None,
    characters=1,
    runtime="torch",
    onnx=None,
    **options,
) -> WalkController:
    """A `WalkController` of a PathWalker, set up as every live front end sets it up (`PathFollower.
    controller`, `walkdiff play`, `control`, the page): `style` None is the model's first style with a
    known walking speed; the sampler named as on the command line (ddim: 10 steps and eta 1 unless
    given); `runtime` 'onnx': its frames made by ONNX Runtime (`export/runtime.py`), from the frame
    exported now or the graph exported into the folder `onnx`."""
    from walkdiff.export.runtime import frame_runtime

    if sampler == "ddim":
        steps, eta = steps or 10, 1.0 if eta is None else eta
    choice = SamplerChoice(sampler, steps, eta or 0.0)
    style = first_style(model) if style is None else style
    frames = frame_runtime(model, runtime, choice, onnx=onnx)
    return WalkController(frames, style, speed, seed, choice, characters, **options)
