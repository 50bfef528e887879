"""MP4 previews (H.264, with the speech as AAC when there is any), written with PyAV.

PyAV's wheels ship FFmpeg's libraries, x264 and AAC encoders included, so no system ffmpeg is needed;
the frames are the same pictures the GIF previews show. yuv420p and even sizes keep the file playable
in every browser and player.
"""

from __future__ import annotations

from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path
from typing import IO

import numpy as np
from PIL import Image

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import write_atomic

AUDIO_BLOCK = 1024  # samples per AAC frame


def _even(image: Image.Image) -> np.ndarray:
    """RGB pixels cropped to even width and height (yuv420p halves both)."""
    w, h = image.size
    return np.asarray(image.convert("RGB"))[: h - h % 2, : w - w % 2]


def write_mp4(
    path: str | Path,
    frames: Iterable[Image.Image],
    fps: float,
    audio: tuple[np.ndarray, int] | None = None,
) -> Path:
    """Encode `frames` shown at `fps` (and mono `audio` = (samples in [-1, 1], rate)) as an MP4 file."""
    import av

    if not (np.isfinite(fps) and fps > 0):
        raise WalkdiffError(f"fps must be a positive number, got {fps}")
    rate = Fraction(fps).limit_denominator(1001)

    def save(f: IO[bytes]) -> None:
        with av.open(f, mode="w", format="mp4") as container:
            video = None
            for k, image in enumerate(frames):
                pixels = _even(image)
                if video is None:
                    video = container.add_stream("libx264", rate=rate)
                    video.height, video.width = pixels.shape[:2]
                    video.pix_fmt = "yuv420p"
                    video.options = {"crf": "20", "preset": "medium"}
                    if audio is not None:
                        sound = container.add_stream("aac", rate=int(audio[1]), layout="mono")
                frame = av.VideoFrame.from_ndarray(pixels, format="rgb24")
                frame.pts, frame.time_base = k, 1 / rate
                container.mux(video.encode(frame))
            if video is None:
                raise WalkdiffError("no frames to write", path=path)
            container.mux(video.encode())
            if audio is not None:
                samples = np.clip(np.asarray(audio[0], dtype=np.float32), -1, 1)
                for start in range(0, len(samples), AUDIO_BLOCK):
                    block = samples[start : start + AUDIO_BLOCK][None]
                    chunk = av.AudioFrame.from_ndarray(block, format="flt", layout="mono")
                    chunk.sample_rate, chunk.pts = int(audio[1]), start
                    container.mux(sound.encode(chunk))
                container.mux(sound.encode())

    return write_atomic(path, save)
