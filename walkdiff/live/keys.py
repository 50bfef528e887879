"""Keys to walking commands: what the arrow keys, WASD, the number keys and R do to a walker, shared by
`walkdiff play --script` and the interactive page.

- ArrowLeft / A and ArrowRight / D turn the commanded direction of travel to the walker's left (the
  heading angle up: from +z towards +x) or right, at `turn_rate` degrees per second while held.
- ArrowUp / W and ArrowDown / S raise or lower the speed by `speed_step` m/s a press (0 at the least,
  `top_speed` at the most). Until the first press the walker walks at its style's own speed.
- 1 .. 9 pick the model's style of that number (1: its first), R toggles recording, C turns the example
  clips the walker was started with (`--style-clip`) off and on again.

Keys are named as a browser's `KeyboardEvent.key` names them (letters in either case). Key releases
matter only for the turning keys. Direct commands (a direction, a speed, a style) set the same state, so
keys go on from where a command left it. This module holds state only: no model, no torch.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from walkdiff.common.errors import WalkdiffError

KEY_TURN_RATE = 90.0  # degrees per second while a turning key is held
SPEED_STEP = 0.2  # m/s a press of up or down
TOP_SPEED = 3.0  # m/s

TURNS = {"arrowleft": 1.0, "a": 1.0, "arrowright": -1.0, "d": -1.0}
SPEEDS = {"arrowup": 1.0, "w": 1.0, "arrowdown": -1.0, "s": -1.0}
RECORD = "r"
CLIP = "c"


class KeyControl:
    """The commanded direction (degrees), speed (m/s, None: the style's own), style and recording of a
    walker steered by keys and commands. `speed_of(style)`: a style's own speed in m/s."""

    def __init__(
        self,
        styles: list[str] | tuple[str, ...],
        speed_of: Callable[[str], float],
        style: str,
        speed: float | None = None,
        direction: float = 0.0,
        recording: bool = True,
        turn_rate: float = KEY_TURN_RATE,
        speed_step: float = SPEED_STEP,
        top_speed: float = TOP_SPEED,
        clips: str | list | None = None,
    ):
        self.styles, self.speed_of = list(styles), speed_of
        self.style, self.speed, self.direction, self.recording = style, speed, float(direction), recording
        self.turn_rate, self.speed_step, self.top_speed = turn_rate, speed_step, top_speed
        self.held: set[str] = set()
        self.style_clips: str | list | None = None  # example clips commanded (None: as the walker started)
        self.clips = clips or None  # the clips C turns off and on

    def key(self, key: str, down: bool = True) -> None:
        """A key pressed (`down`) or released; an unknown key is a WalkdiffError naming the known ones."""
        if not isinstance(key, str) or not key:
            raise WalkdiffError(f"key: expected a key name (ArrowLeft, w, 1, r, ...), got {key!r}")
        name = key.lower()
        if name in TURNS:
            (self.held.add if down else self.held.discard)(name)
        elif not down:
            if name not in SPEEDS and name not in (RECORD, CLIP) and not name.isdigit():
                raise self._unknown(key)
        elif name in SPEEDS:
            speed = self.speed if self.speed is not None else self.speed_of(self.style)
            self.speed = round(min(max(speed + SPEEDS[name] * self.speed_step, 0.0), self.top_speed), 6)
        elif name == RECORD:
            self.recording = not self.recording
        elif name == CLIP:
            if self.clips is None:
                raise WalkdiffError("key c: no example clips to turn on: start with --style-clip FILE")
            on = bool(self.clips) if self.style_clips is None else bool(self.style_clips)
            self.style_clips = "" if on else self.clips
        elif name.isdigit() and name != "0" and len(name) == 1:
            number = int(name)
            if number > len(self.styles):
                raise WalkdiffError(
                    f"key {key}: the model has {len(self.styles)} styles (keys 1-{len(self.styles)})"
                )
            self.style = self.styles[number - 1]
        else:
            raise self._unknown(key)

    def command(
        self, direction: float | None = None, speed: float | None = None, style: str | None = None,
        style_clips: str | list | None = None,
    ):  # fmt: skip
        """A direct command: a direction in degrees, a speed in m/s, a style, example clips ("": none);
        None keeps a field."""
        if direction is not None:
            self.direction = float(direction)
        if speed is not None:
            self.speed = float(speed)
        if style is not None:
            self.style = style
        if style_clips is not None:
            self.style_clips = style_clips

    def tick(self, seconds: float) -> None:
        """Time passes with the keys held as they are: the turning keys turn the direction."""
        turn = sum(TURNS[k] for k in self.held)
        if turn:
            self.direction = math.remainder(self.direction + turn * self.turn_rate * seconds, 360.0)

    def state(self) -> dict:
        """The command to walk by now: direction (degrees), speed (m/s, None: the style's own), style,
        recording."""
        return {
            "direction": self.direction,
            "speed": self.speed,
            "style": self.style,
            "style_clips": self.style_clips,
            "recording": self.recording,
        }

    @staticmethod
    def _unknown(key: str) -> WalkdiffError:
        return WalkdiffError(
            f"key {key!r}: expected ArrowLeft/ArrowRight/ArrowUp/ArrowDown, w/a/s/d, 1-9 (a style), r "
            "(recording) or c (example clips)"
        )
