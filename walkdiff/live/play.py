"""Walkers steered live from outside Python and from scripts: `walkdiff control` (commands as JSON lines on
stdin, a pose per frame as a JSON line on stdout) and `walkdiff play --script` (timed key events and
commands replayed headless into a take written as BVH, glb and the commands per frame).

Both drive a `WalkController` (walkdiff/walker/controller.py); keys go through `KeyControl`
(walkdiff/live/keys.py) and `Replay`, which the interactive page (`page.py`) shares.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free, output_folder, output_set, read_utf8, write_json
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.common.progress import progress
from walkdiff.live.keys import RECORD, KeyControl
from walkdiff.motion.bvh import write_bvh
from walkdiff.motion.gltf import write_glb
from walkdiff.motion.resample import resample
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig
from walkdiff.streams.lines import StreamEnd, emit, stopped
from walkdiff.walker.controller import WalkController, angle_of, checked_speed, style_weights

COMMANDS = ("direction", "speed", "style", "style_clips")
CONTROL_FIELDS = (*COMMANDS, "character", "frames", "record")
SCRIPT_FIELDS = ("t", "key", "down", *COMMANDS)
MOST_FRAMES_A_LINE = 100_000  # about 55 minutes at 30 fps


@contextmanager
def at_line(where: str, line: int | None) -> Iterator[None]:
    """Errors raised inside name `where` and `line`, before the file they name if another (a clip the
    line asked for)."""
    try:
        yield
    except WalkdiffError as error:
        if line is None or (error.path is not None and str(error.path) == where):
            raise
        reason = error.reason if error.path is None else str(error)
        raise WalkdiffError(reason, path=where, line=line) from None


def json_object(text: bytes | str, where: str, line: int, expected: str) -> dict | None:
    """A JSON line as a dict (None for a blank line), or a WalkdiffError naming the line."""
    if not text.strip():
        return None
    try:
        data = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError):
        data = None
    if not isinstance(data, dict):
        shown = (text.decode("utf-8", "replace") if isinstance(text, bytes) else text).strip()[:60]
        raise WalkdiffError(f"expected a JSON object {expected}, got {shown!r}", path=where, line=line)
    return data


def known_fields(data: dict, fields: tuple[str, ...], where: str, line: int) -> None:
    unknown = [name for name in data if name not in fields]
    if unknown:
        raise WalkdiffError(
            f"unknown field {unknown[0]!r}; expected {', '.join(fields)}", path=where, line=line
        )


def command_of(data: dict, model, where: str, line: int) -> dict:
    """The command fields of a line, checked: direction in degrees, speed in m/s, style as given."""
    with at_line(where, line):
        command = {}
        if "direction" in data:
            command["direction"] = math.degrees(angle_of(data["direction"]))
        if "speed" in data:
            command["speed"] = checked_speed(data["speed"])
        if "style" in data:
            if not isinstance(data["style"], str | list):
                raise WalkdiffError(
                    f"style: expected a name, a mix 'angry:0.7,old:0.3' or weights, got {data['style']!r}"
                )
            style_weights(model, data["style"])
            command["style"] = data["style"]
        if "style_clips" in data:  # read when applied: a bad clip names this line then
            clips = data["style_clips"]
            listed = isinstance(clips, list) and all(isinstance(c, str) for c in clips)
            if not (isinstance(clips, str) or listed):
                raise WalkdiffError(
                    f"style_clips: expected 'a.bvh:0.7,b.bvh', a list of BVH paths or \"\" (none), "
                    f"got {clips!r}"
                )
            command["style_clips"] = clips
        return command


def whole(data: dict, name: str, low: int, high: int) -> int:
    value = data[name]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise WalkdiffError(f"{name}: expected a whole number from {low} to {high}, got {value!r}")
    return value


# ---------------------------------------------------------------- the takes and their files


def take_files(out: Path, characters: int, name: str = "take") -> list[Path]:
    names = [name] if characters == 1 else [f"{name}_{k}" for k in range(characters)]
    return [out / f"{n}{suffix}" for n in names for suffix in (".bvh", ".glb")] + [out / f"{name}.json"]


def write_takes(
    out: Path,
    walker: WalkController,
    manifest: dict,
    fps: float | None = None,
    name: str = "take",
    rig: TargetRig | None = None,
) -> list[Path]:
    """Each character's recorded frames as BVH and glb (at `fps`, default the model's; played by `rig`
    when given, --to), and take.json (`name`.json): all or none."""
    files = take_files(out, walker.characters, name)
    with output_set(out):
        for k in range(walker.characters):
            take = walker.take(k)
            if fps is not None and abs(fps - take.fps) > 1e-9:
                take = Take(resample(take.motion, fps), take.profile)
            take = take if rig is None else take.retarget(rig)
            write_bvh(files[2 * k], take.motion)
            write_glb(files[2 * k + 1], take.canonical(), take.metres_per_unit)
        retarget = {} if rig is None else {"retarget": rig.record()}
        write_json(files[-1], manifest | retarget | {"files": [str(f) for f in files]})
    return files


def settings(ckpt, walker: WalkController, fps=None) -> dict:
    return {
        "checkpoint": str(ckpt), "style": walker.start_style, "speed_m_s": walker.start_speed,
        "seed": walker.seed, "sampler": walker.sampler.label(walker.model.diffusion),
        "runtime": getattr(walker.model, "runtime", "torch"), "model_fps": walker.fps,
        "written_fps": fps or walker.fps, "characters": walker.characters,
        "transition_s": walker.transition, "turn_rate_deg_s": math.degrees(walker.turn_rate),
        "heading_assist_deg_s": math.degrees(walker.heading_assist), "foot_lock": walker.lock is not None,
        "style_clips": walker.start_clips or None,
        "match_clips": walker.match_clips if walker.guide is not None else None,
    }  # fmt: skip


def keys_for(walker: WalkController, recording: bool) -> KeyControl:
    """The keys of a walker, starting from its style, speed and example clips (C turns those off and on)."""
    return KeyControl(
        walker.styles, walker.speed_of, walker.start_style, walker.start_speed, recording=recording,
        clips=walker.style_clips,
    )  # fmt: skip


def load_walker(ckpt, **options) -> WalkController:
    """The walker a live command steers: `PathFollower.controller` of the checkpoint."""
    from walkdiff.walker.follow import PathFollower

    return PathFollower.load(ckpt).controller(**options)


# ---------------------------------------------------------------- walkdiff play --script


@dataclass
class Event:
    """A line of a script: at `t` seconds a key (pressed or released) or a command (or nothing: a mark
    the take lasts until)."""

    line: int
    t: float
    key: str | None = None
    down: bool = True
    command: dict = field(default_factory=dict)


def read_script(path: str | Path, model) -> list[Event]:
    """The events of a script file, checked: times from 0 up, known fields, keys and commands valid."""
    where, events = str(path), []
    if not Path(path).is_file():
        raise WalkdiffError("file not found", path=path)
    expected = '{"t": seconds, "key": "ArrowLeft", "down": true} or {"t": seconds, "direction": [x, z], ...}'
    for number, text in enumerate(read_utf8(Path(path), "the script").splitlines(), 1):
        data = json_object(text, where, number, expected)
        if data is None:
            continue
        known_fields(data, SCRIPT_FIELDS, where, number)
        t = data.get("t")
        if isinstance(t, bool) or not isinstance(t, int | float) or not (math.isfinite(t) and t >= 0):
            raise WalkdiffError(f"t: expected seconds >= 0, got {t!r}", path=where, line=number)
        if events and t < events[-1].t:
            raise WalkdiffError(f"t: {t} is before the line above's {events[-1].t}", path=where, line=number)
        command = command_of(data, model, where, number)
        if "key" in data and command:
            raise WalkdiffError("a line is a key event or a command, not both", path=where, line=number)
        if "down" in data and (not isinstance(data["down"], bool) or "key" not in data):
            raise WalkdiffError("down: expected true or false, with a key", path=where, line=number)
        events.append(Event(number, float(t), data.get("key"), data.get("down", True), command))
    if not events or events[-1].t <= 0:
        raise WalkdiffError(
            'no time to play: end the script with a line at the take\'s end, {"t": 10}', path=where
        )
    return events


class Replay:
    """A script's events applied to keys and a controller, frame by frame."""

    def __init__(self, walker: WalkController, keys: KeyControl, events: list[Event], where: str):
        self.walker, self.keys, self.events, self.where = walker, keys, events, where
        self.next = 0
        self.applied = keys.state()
        walker.record = self.applied["recording"]

    def due(self, frame: int) -> None:
        """Apply the events due by this frame's time, each to the keys then the controller."""
        now = frame / self.walker.fps + 1e-9
        while self.next < len(self.events) and self.events[self.next].t <= now:
            event = self.events[self.next]
            with at_line(self.where, event.line):
                if event.key is not None:
                    self.keys.key(event.key, event.down)
                else:
                    self.keys.command(**event.command)
                self.update()
            self.next += 1

    def update(self) -> None:
        """Command the controller with what changed in the keys' state."""
        state = self.keys.state()
        changed = {k: state[k] for k in COMMANDS if state[k] != self.applied[k] and state[k] is not None}
        if changed:
            self.walker.command(**changed)
        self.walker.record = state["recording"]
        self.applied = state

    def tick(self) -> None:
        self.keys.tick(1 / self.walker.fps)
        self.update()


def play(
    ckpt: str,
    script: str | None,
    out: str | None,
    fps: float | None = None,
    overwrite: bool = False,
    to=None,
    to_map=None,
    **options,
) -> dict:
    """`walkdiff play --script`: the script's key events and commands replayed at the model's frame rate,
    the frames recorded written as take.bvh, take.glb and take.json (the commands per frame), at `fps`
    and played by `to` (+ `to_map`) when given. `options`: the walker's, as `PathFollower.controller`
    takes them (style, speed, seed, the sampler, transition, turn_rate, ...)."""
    if script is None:
        raise WalkdiffError(
            "play: give a script (JSON lines of timed key events and commands) to play a take headless; "
            "`walkdiff play` without --script (walkdiff.live.page) serves the page"
        )
    if out is None:
        raise WalkdiffError("--out: give the folder for take.bvh, take.glb and take.json")
    rig = TargetRig.of(to, to_map)
    out = output_folder(out)
    check_free(take_files(out, 1), overwrite)
    walker = load_walker(ckpt, **options)
    events = read_script(script, walker.model)
    started = time.perf_counter()
    log, held = replay(walker, events, str(script))
    manifest = settings(ckpt, walker, fps) | {
        "script": str(script), "frames": len(log), "recorded_frames": len(walker.kept),
        "generation_seconds": round(time.perf_counter() - started, 2),
        "keys_held_at_end": held, "commands": log,
    }  # fmt: skip
    write_takes(out, walker, manifest, fps, rig=rig)
    return {k: v for k, v in manifest.items() if k != "commands"} | {
        "files": [str(f) for f in take_files(out, 1)]
    }


def replay(walker: WalkController, events: list[Event], where: str) -> tuple[list[dict], list[str]]:
    """A script's events played on the walker until its last line's time, every line checked on a fork
    first (before any work): each frame's command as the log records it, and the keys held at the end."""
    frames = round(events[-1].t * walker.fps)
    check_frames("--script", frames, WALK_BYTES_PER_FRAME)
    pressed = any(e.key is not None and e.key.lower() == RECORD for e in events)
    dry = Replay(walker.fork(), keys_for(walker, not pressed), events, where)
    for frame in range(frames + 1):
        dry.due(frame)
    played, log = Replay(walker, keys_for(walker, not pressed), events, where), []
    with progress(desc="playing", unit="frame", total=frames) as bar:
        for frame in range(frames):
            played.due(frame)
            log.append(
                {"frame": frame, "time": round(frame / walker.fps, 4), "recording": walker.record}
                | walker.commanded()
            )
            walker.advance()
            played.tick()
            bar.update(1)
    if not walker.kept:
        raise WalkdiffError(
            "no frame was recorded: the script's 'r' presses left recording off throughout", path=where
        )
    return log, sorted(played.keys.held)


# ---------------------------------------------------------------- walkdiff control: JSON lines


def header(walker: WalkController) -> dict:
    profile = walker.model.profile
    return {
        "fps": walker.fps, "joints": walker.joints, "units_per_metre": 1 / profile.metres_per_unit,
        "styles": list(walker.styles), "characters": walker.characters,
        "root": "position of the first joint, in the BVH's units and axes",
        "rotation": "local to the parent joint, quaternion [x, y, z, w], on the BVH's skeleton and axes",
        "positions": "world position of every joint, in metres, Y up (walkdiff's axes)",
        "heading": "the root's facing in degrees about +Y: 0 towards +z, 90 towards +x",
    }  # fmt: skip


def frame_line(pose, fps: float, latency: float, characters: int) -> dict:
    line = {"frame": pose.frame, "time": round(pose.frame / fps, 4), "latency_ms": latency}
    if characters > 1:
        line["character"] = pose.character
    return line | {
        "root": pose.translation.round(4).tolist(), "heading": round(pose.heading, 3),
        "positions": pose.positions.round(4).tolist(), "rotations": pose.rotations.round(5).tolist(),
    }  # fmt: skip


def apply_line(walker: WalkController, data: dict, out: Path | None, where: str, number: int) -> int:
    """A control line's commands given to the walker (all checked first: a bad line changes nothing);
    the frames it asks for."""
    known_fields(data, CONTROL_FIELDS, where, number)
    command = command_of(data, walker.model, where, number)
    with at_line(where, number):
        character = whole(data, "character", 0, walker.characters - 1) if "character" in data else None
        frames = whole(data, "frames", 0, MOST_FRAMES_A_LINE) if "frames" in data else 1
        if "record" in data and (not isinstance(data["record"], bool) or out is None):
            raise WalkdiffError("record: expected true or false, with --out (where the take is written)")
        walker.command(**command, character=character)
    walker.record = data.get("record", walker.record)
    return frames


def control(
    ckpt: str,
    out: str | None = None,
    overwrite: bool = False,
    to=None,
    to_map=None,
    characters: int = 1,
    **options,
) -> dict:
    """`walkdiff control`: commands as JSON lines on stdin, one JSON line per frame (and character) on
    stdout as soon as it is made; with `out`, the recorded take written at the end (also when a bad line
    stops it: the frames made so far are kept). `options`: the walker's, as `play`'s."""
    where = "-"
    rig = TargetRig.of(to, to_map)
    if rig is not None and out is None:
        raise WalkdiffError(
            "--to plays the take written with --out; give --out (the live lines stay on the model's skeleton)"
        )
    folder = None if out is None else output_folder(out)
    if folder is not None:
        check_free(take_files(folder, characters), overwrite)
    walker = load_walker(ckpt, characters=characters, record=folder is not None, **options)
    emit(header(walker))
    log, end, started = [], StreamEnd(), time.perf_counter()
    with end.watch():  # a bad line or Ctrl-C: the frames made so far are kept, and written with --out
        for number, text in enumerate(iter(sys.stdin.buffer.readline, b""), 1):
            arrived = time.perf_counter()
            data = json_object(text, where, number, '{"direction": [x, z], "speed": m/s, "style": name}')
            if data is None:
                continue
            frames = apply_line(walker, data, folder, where, number)
            if walker.record:
                with at_line(where, number):
                    check_frames("frames", len(walker.kept) + frames, WALK_BYTES_PER_FRAME, characters)
            for _ in range(frames):
                entry = {"frame": walker.frame, "recording": walker.record}
                log.append(entry | {"commands": [walker.commanded(k) for k in range(characters)]})
                poses = walker.advance()
                latency = round(1000 * (time.perf_counter() - arrived), 1)
                for pose in poses:
                    emit(frame_line(pose, walker.fps, latency, characters))
    files = []
    if folder is not None and walker.kept:
        manifest = settings(ckpt, walker) | {
            "source": "stdin", "frames": walker.frame, "recorded_frames": len(walker.kept),
            "error": None if end.error is None else str(end.error) or "interrupted", "commands": log,
        }  # fmt: skip
        files = write_takes(folder, walker, manifest, rig=rig)
    if end.error is not None:
        raise stopped(end.error, walker.frame, files)
    summary = {
        "done": True, "frames": walker.frame, "recorded_frames": len(walker.kept),
        "wall_s": round(time.perf_counter() - started, 3), "files": [str(f) for f in files],
    }  # fmt: skip
    emit(summary)
    return summary
