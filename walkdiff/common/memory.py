"""Memory estimates of long outputs, checked before any work.

A command's memory grows with the frames it makes (features, decoded rotations, BVH text a chunk at a
time), so a frame count from `--frames`, a path's length or a WAV's duration is turned into an estimate
and refused above the limit with the option that asked for it. The per-frame costs are measured by
`walkdiff bench memory` (peak RSS of the real commands); the limit is 4 GB unless
WALKDIFF_MEMORY_LIMIT_GB says otherwise.
"""

from __future__ import annotations

import math
import os

from walkdiff.common.errors import WalkdiffError

LIMIT_ENV = "WALKDIFF_MEMORY_LIMIT_GB"
DEFAULT_LIMIT_GB = 4.0
BASE_BYTES = 700e6  # Python, torch and a model loaded: a 300-frame `sample` peaks at ~530 MB

# Bytes per generated frame and clip, from `walkdiff bench memory` (the slope of peak RSS between a short
# and a long run, both with a full 20-s preview where there is one, rounded up), on the shapes of
# conf/xia_cpu.yaml, conf/walk_xia.yaml and conf/diffmotion_zeggs.yaml:
# sample 6.4 kB (552 MB at 300 frames, 1231 MB at 100,000), walk 4.1 kB (610 MB at 901, 636 MB at 7,201),
# gesture 19.8 kB (703 MB at 600, 786 MB at 4,800: audio windows and the mel spectrogram per frame).
SAMPLE_BYTES_PER_FRAME = 8_000
WALK_BYTES_PER_FRAME = 6_000
GESTURE_BYTES_PER_FRAME = 24_000


def memory_limit() -> float:
    """The limit in bytes: WALKDIFF_MEMORY_LIMIT_GB, or 4 GB."""
    text = os.environ.get(LIMIT_ENV)
    if text is None:
        return DEFAULT_LIMIT_GB * 1e9
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise WalkdiffError(f"{LIMIT_ENV}: expected a positive number of gigabytes, got {text!r}")
    return value * 1e9


def check_frames(option: str, frames: int, bytes_per_frame: float, clips: int = 1) -> float:
    """Refuse `clips` clips of `frames` frames whose estimated peak memory is above the limit; return the
    estimate in bytes. `option` names what set the frame count (--frames, --path, --audio)."""
    estimate = BASE_BYTES + frames * clips * bytes_per_frame
    limit = memory_limit()
    if estimate > limit:
        most = max(0, int((limit - BASE_BYTES) / (bytes_per_frame * clips)))
        raise WalkdiffError(
            f"{option}: {frames} frames{f' x {clips} clips' if clips > 1 else ''} would need about "
            f"{estimate / 1e9:.2f} GB of memory, above the limit of {limit / 1e9:.2f} GB (at most {most} "
            f"frames); make shorter clips, or raise the limit with {LIMIT_ENV}"
        )
    return estimate
