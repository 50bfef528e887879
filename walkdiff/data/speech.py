"""Speech-gesture takes: a BVH and a WAV with the same stem (ZEGGS, Trinity / GENEA 2020), for DiffMotion.

Each take becomes two aligned per-frame arrays at the motion frame rate (20 fps by default):

    poses  (F, J k)   local rotations of a joint subset (default: the upper body from the first spine joint
                      to head and hands, no fingers, as DiffMotion); k = 3 for exponential maps (rotation
                      vectors, the paper), 6 for the 6D representation
    audio  (F, M)     M-band log-mel power (M = 27), mel frame k centred on motion frame k

Takes are read on the canonical skeleton of their profile (`walkdiff.motion.profile`: the body below
the joint that carries the root motion, Y up), so any skeleton works, and decoded clips go back onto the
takes' own skeleton, axes and units. The root's translation and the joints outside the subset are not
modelled: a decoded pose puts them in a neutral pose, the chordal mean of their training rotations (and
the mean root position), so the BVH goes back onto the full training skeleton. Every take trains on
its first `train_fraction` of frames and tests on the rest; with one take (ZEGGS here) validation uses
the test part.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import roma
import torch
from torch.utils.data import Dataset

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.paths import dataset_dir
from walkdiff.data.datamodule import WindowLoaders
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import Normalizer
from walkdiff.motion.resample import resample
from walkdiff.motion.rotations import matrix_to_6d, sixd_to_matrix
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.spec import NeutralPose, SpeechSpec

log = logging.getLogger(__name__)

ROTATIONS = {"expmap": 3, "6d": 6}  # representation -> numbers per joint
FINGER_WORDS = ("thumb", "index", "middle", "ring", "pinky", "finger")
LOG_FLOOR = 1e-10  # added to the mel power before the log: digital silence stays finite


# ---------------------------------------------------------------- audio


def wav_info(path: str | Path):
    """An audio file's header (soundfile's info: frames, samplerate, ...), without reading its samples."""
    import soundfile

    try:
        return soundfile.info(str(path))
    except (OSError, RuntimeError, soundfile.LibsndfileError) as error:
        raise WalkdiffError(f"cannot read the audio file ({error})", path=path) from None


def wav_seconds(path: str | Path) -> float:
    """The duration of an audio file from its header, without reading its samples."""
    info = wav_info(path)
    return info.frames / info.samplerate


def read_wav(path: str | Path) -> tuple[np.ndarray, int]:
    """Mono float32 samples and the sample rate (channels are averaged)."""
    import soundfile

    try:
        samples, rate = soundfile.read(str(path), dtype="float32", always_2d=True)
    except (OSError, RuntimeError, soundfile.LibsndfileError) as error:
        raise WalkdiffError(f"cannot read the audio file ({error})", path=path) from None
    if samples.shape[0] == 0:
        raise WalkdiffError("the audio file has no samples", path=path)
    bad = ~np.isfinite(samples).all(axis=1)
    if bad.any():  # float WAVs can hold NaN/inf; they would turn every mel frame after them into NaN
        first = int(np.argmax(bad))
        raise WalkdiffError(
            f"{int(bad.sum())} sample(s) are not finite numbers, the first at {first / rate:.3f} s "
            f"(sample {first}); expected audio in [-1, 1]",
            path=path,
        )
    return samples.mean(axis=1), int(rate)


def frame_aligned_rate(rate: int, fps: float) -> int:
    """A sample rate at which one motion frame is a whole number of samples (the mel hop)."""
    return rate if (rate / fps).is_integer() else int(round(rate / fps) * fps)


def log_mel(samples: np.ndarray, rate: int, fps: float, bands: int = 27) -> np.ndarray:
    """(F, bands) float32 log mel power, one frame per motion frame: frame k is centred at k / fps.

    The hop is one motion frame, the analysis window two (100 ms at 20 fps). A rate that does not
    divide into motion frames is resampled to the nearest one that does.
    """
    import librosa

    target = frame_aligned_rate(rate, fps)
    if target != rate:
        samples = librosa.resample(samples, orig_sr=rate, target_sr=target)
    hop = int(target / fps)
    n_fft = 1 << math.ceil(math.log2(2 * hop))
    mel = librosa.feature.melspectrogram(
        y=samples, sr=target, n_fft=n_fft, hop_length=hop, win_length=2 * hop, n_mels=bands, power=2.0
    )
    return np.log(mel + LOG_FLOOR).T.astype(np.float32)


def samples_per_frame(rate: int, fps: float, where: str) -> int:
    """The mel hop of streamed audio: a rate must give whole samples per motion frame (no resampling,
    which would not give the offline features piece by piece)."""
    if not (rate / fps).is_integer():
        raise WalkdiffError(
            f"{where}: {rate} Hz is not a whole number of samples per frame at {fps:g} fps; streaming needs "
            f"a rate that is (e.g. {frame_aligned_rate(rate, fps)} Hz): resample the audio"
        )
    return int(rate / fps)


class LogMelBatch:
    """`log_mel` of many streams' audio arriving in pieces: the same frames, each computable as soon as
    its window is in. A row's samples are appended to its buffer as they come (`push`: a copy, nothing
    computed); `compute` then makes every frame completed since, of all rows, in one go: one gather of
    the windows, one FFT, one log.

    Mel frame k is centred on sample k * hop with a 2-hop window, so it needs the samples before
    (k + 1) * hop; `finish` adds a row's frames whose windows run past its end, zero-padded as `log_mel`
    pads them (librosa's centred STFT). The window and mel filters are librosa's, made once: building
    the filters is ~30 ms, which librosa's melspectrogram would pay on every call. The mel projection
    is one BLAS product per push, run stacked by the number of frames the push completed: BLAS rounds a
    product of k columns differently for each k (and for one column, a matrix-vector product), and
    this keeps each frame the float a stream computing its pushes one by one gets.
    """

    def __init__(self, rate: int, fps: float, bands: int = 27, where: str = "audio"):
        import librosa

        self.rate, self.bands = rate, bands
        self.hop = samples_per_frame(rate, fps, where)
        self.n_fft = 1 << math.ceil(math.log2(2 * self.hop))
        window = librosa.filters.get_window("hann", 2 * self.hop, fftbins=True)
        self.window = librosa.util.pad_center(window, size=self.n_fft).astype(np.float32)
        self.mel_basis = librosa.filters.mel(sr=rate, n_fft=self.n_fft, n_mels=bands)
        # Frame k reads samples [k hop - n_fft/2, k hop + n_fft/2); its window is non-zero on the middle
        # 2 hops of that span, so the last sample it needs is k hop - n_fft/2 + `self.reach` - 1.
        self.reach = (self.n_fft - 2 * self.hop) // 2 + 2 * self.hop
        # Each row's samples from `offset` (the first window starts n_fft/2 before sample 0, on the centred
        # STFT's zeros), `filled` of them, then zeros: a window reaching past the samples in reads zeros.
        self.buffer = np.zeros((0, 4 * self.n_fft), np.float32)
        self.offset: list[int] = []
        self.filled: list[int] = []
        self.received: list[int] = []  # samples pushed, per row
        self.frames: list[int] = []  # frames the samples so far complete (computed or pending), per row
        self.computed: list[int] = []  # frames computed, per row
        self.finished: list[bool] = []
        self.pending: list[tuple[int, int, int]] = []  # (row, first frame, end frame) per push, in order

    @property
    def rows(self) -> int:
        return len(self.received)

    def add(self) -> int:
        """A new row (a stream at its start); its index."""
        if self.rows == len(self.buffer):  # rows grow by doubling: a batch of n streams copies O(n) rows
            grown = np.zeros((max(1, 2 * self.rows), self.buffer.shape[1]), np.float32)
            grown[: self.rows] = self.buffer[: self.rows]
            self.buffer = grown
        self.offset.append(-(self.n_fft // 2))
        self.filled.append(self.n_fft // 2)
        for state in (self.received, self.frames, self.computed):
            state.append(0)
        self.finished.append(False)
        return self.rows - 1

    def needed(self, frame: int) -> int:
        """Samples that must have arrived before `frame` can be computed (before the end is known)."""
        return frame * self.hop - self.n_fft // 2 + self.reach

    def push(self, row: int, samples: np.ndarray) -> int:
        """Mono float samples (any number) for `row`; the frames they complete (`compute` makes them)."""
        if self.finished[row]:
            raise WalkdiffError("audio pushed after the end of the stream")
        samples = np.asarray(samples, dtype=np.float32).reshape(-1)
        filled, count = self.filled[row], len(samples)
        if filled + count + self.n_fft > self.buffer.shape[1]:  # room for it and the windows past it
            filled = self._room(row, count)
        self.buffer[row, filled : filled + count] = samples
        self.filled[row] = filled + count
        self.received[row] += count
        # frame k is complete once needed(k) <= received
        end = (self.received[row] + self.n_fft // 2 - self.reach) // self.hop + 1
        return self._complete(row, end)

    def finish(self, row: int) -> int:
        """The end of `row`'s audio: the frames left (`log_mel` has 1 + samples // hop in all)."""
        self.finished[row] = True
        return self._complete(row, 1 + self.received[row] // self.hop)

    def compute(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every frame completed since the last call, of all rows: their rows (N,), frame numbers (N,) and
        log-mel values (N, bands) float32, in the order they were completed."""
        pending, self.pending = self.pending, []
        if not pending:
            empty = np.zeros(0, np.int64)
            return empty, empty, np.zeros((0, self.bands), np.float32)
        rows, starts, ends = np.array(pending, dtype=np.int64).T
        sizes = ends - starts
        at = np.cumsum(sizes) - sizes  # each push's first position in the output
        row_of = np.repeat(rows, sizes)
        frame = np.arange(len(row_of)) - np.repeat(at - starts, sizes)
        column = frame * self.hop - self.n_fft // 2 - np.asarray(self.offset)[row_of]
        windows = np.lib.stride_tricks.sliding_window_view(self.buffer, self.n_fft, axis=1)[row_of, column]
        windows *= self.window
        power = np.abs(np.fft.rfft(windows, axis=1)) ** 2.0  # (N, n_fft / 2 + 1)
        mel = np.empty((len(row_of), self.bands), np.float32)
        counts = np.unique(sizes)
        for k in counts.tolist():  # the pushes that completed k frames: one stacked product
            same = at if len(counts) == 1 else at[sizes == k]
            spots = same[:, None] + np.arange(k)  # (pushes, k) output positions
            products = np.matmul(self.mel_basis, power[spots].transpose(0, 2, 1))  # (pushes, bands, k)
            mel[spots] = products.transpose(0, 2, 1)
        self.computed = list(self.frames)
        return row_of, frame, np.log(mel + LOG_FLOOR)

    def _complete(self, row: int, end: int) -> int:
        if end <= self.frames[row]:
            return 0
        self.pending.append((row, self.frames[row], end))
        done, self.frames[row] = end - self.frames[row], end
        return done

    def _room(self, row: int, count: int) -> int:
        """Room in `row`'s buffer for `count` more samples and a window's span of zeros after them: the
        samples before its next window to compute dropped, then the buffer widened if still needed; the
        row's new fill."""
        keep = self.computed[row] * self.hop - self.n_fft // 2 - self.offset[row]  # its first sample
        filled = self.filled[row] - keep
        self.buffer[row, :filled] = self.buffer[row, keep : self.filled[row]]
        self.buffer[row, filled : self.filled[row]] = 0.0
        self.offset[row] += keep
        self.filled[row] = filled
        if filled + count + self.n_fft > self.buffer.shape[1]:
            width = max(2 * self.buffer.shape[1], filled + count + self.n_fft)
            wider = np.zeros((len(self.buffer), width), np.float32)
            wider[:, : self.buffer.shape[1]] = self.buffer
            self.buffer = wider
        return filled


class LogMelStream:
    """`log_mel` of one stream's audio arriving in pieces (a `LogMelBatch` of one row): each `push`
    returns the (n, bands) frames it completed, `finish` the frames left at the end."""

    def __init__(self, rate: int, fps: float, bands: int = 27, where: str = "audio"):
        self.batch = LogMelBatch(rate, fps, bands, where)
        self.row = self.batch.add()
        self.hop, self.n_fft = self.batch.hop, self.batch.n_fft

    @property
    def received(self) -> int:
        return self.batch.received[self.row]

    @property
    def frames(self) -> int:
        """Frames out so far."""
        return self.batch.frames[self.row]

    def needed(self, frame: int) -> int:
        return self.batch.needed(frame)

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Mono float samples (any number) -> the (n, bands) frames they complete."""
        self.batch.push(self.row, samples)
        return self.batch.compute()[2]

    def finish(self) -> np.ndarray:
        """The frames left once the audio has ended."""
        self.batch.finish(self.row)
        return self.batch.compute()[2]


def onset_times(samples: np.ndarray, rate: int) -> np.ndarray:
    """Audio onsets (seconds), librosa's spectral-flux onset detector."""
    import librosa

    return librosa.onset.onset_detect(y=samples, sr=rate, units="time")


# ---------------------------------------------------------------- poses


def default_joints(skeleton: Skeleton) -> list[str]:
    """The first spine joint and everything below it, without fingers and 'End' leaf joints."""
    spine = next((i for i, n in enumerate(skeleton.names) if "spine" in n.lower()), None)
    if spine is None:
        raise WalkdiffError("no joint named Spine*: give data.joints (the joint names to model) explicitly")
    below = {spine}
    for j in range(spine + 1, skeleton.num_joints):  # parents precede children
        if skeleton.parents[j] in below:
            below.add(j)
    return [
        skeleton.names[j]
        for j in sorted(below)
        if not any(w in skeleton.names[j].lower() for w in FINGER_WORDS)
        and not skeleton.names[j].lower().endswith("end")
    ]


def _continuous_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(F, J, 3) rotation vectors made continuous over frames.

    A rotation vector jumps from angle ~pi to ~-pi when a joint turns through pi (ZEGGS's hands
    reach 179 degrees). v (1 + 2 pi k / |v|) is the same rotation for any integer k; each frame takes
    the k that lands nearest the previous frame, so the features stay smooth for the network.
    """
    out = rotvec.copy()
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    axis = np.divide(rotvec, angle, out=np.zeros_like(rotvec), where=angle > 1e-8)
    for f in range(1, len(out)):
        along = np.sum(out[f - 1] * axis[f], axis=-1, keepdims=True)
        k = np.round((along - angle[f]) / (2 * np.pi))
        out[f] = axis[f] * (angle[f] + 2 * np.pi * k)
    return out


def encode_poses(motion: Motion, joints: list[int], rotation: str) -> np.ndarray:
    """(F, len(joints) * k) float32 local rotations of `joints` (see the module docstring)."""
    if rotation not in ROTATIONS:
        raise WalkdiffError(f"data.rotation must be one of {', '.join(ROTATIONS)}, got {rotation!r}")
    matrices = torch.tensor(motion.rotations[:, joints])
    if rotation == "6d":
        values = matrix_to_6d(matrices).numpy()
    else:
        values = _continuous_rotvec(roma.rotmat_to_rotvec(matrices).numpy())
    return values.reshape(motion.num_frames, -1).astype(np.float32)


def pose_matrices(features: np.ndarray, rotation: str) -> np.ndarray:
    """(F, J k) features -> (F, J, 3, 3) float64 rotation matrices."""
    x = torch.tensor(np.asarray(features), dtype=torch.float64)
    x = x.reshape(x.shape[0], -1, ROTATIONS[rotation])
    matrices = sixd_to_matrix(x) if rotation == "6d" else roma.rotvec_to_rotmat(x)
    return matrices.numpy()


def decode_poses(
    features: np.ndarray,
    skeleton: Skeleton,
    joints: list[int],
    rotation: str,
    neutral: NeutralPose,
    frame_time: float,
) -> Motion:
    """A clip on the full skeleton: the modelled joints from `features`, everything else neutral."""
    frames = len(features)
    rotations = np.repeat(neutral.rotations[None], frames, axis=0)
    rotations[:, joints] = pose_matrices(features, rotation)
    positions = np.repeat(skeleton.offsets[None], frames, axis=0)
    positions[:, 0] = neutral.root
    return Motion(skeleton, rotations, positions, frame_time)


# ---------------------------------------------------------------- takes


@dataclass
class SpeechTake:
    name: str
    bvh: Path
    wav: Path
    motion: Motion  # resampled to the motion frame rate
    audio: np.ndarray  # (F, bands) log mel, aligned with the motion's frames


def list_takes(folder: Path) -> list[tuple[Path, Path]]:
    """(bvh, wav) pairs of a folder, matched by stem; an unpaired file is an error naming it."""
    bvhs = {p.stem: p for p in sorted(folder.glob("*.bvh"))}
    wavs = {p.stem: p for p in sorted(folder.glob("*.wav"))}
    unpaired = sorted(set(bvhs) ^ set(wavs))
    if unpaired:
        names = [str(bvhs.get(s) or wavs.get(s)) for s in unpaired]
        raise WalkdiffError(
            f"expected every take as a BVH and a WAV with the same stem; unpaired: {', '.join(names)}",
            path=folder,
        )
    if not bvhs:
        raise WalkdiffError("no BVH + WAV takes found (expected NAME.bvh with NAME.wav)", path=folder)
    return [(bvhs[s], wavs[s]) for s in sorted(bvhs)]


def load_take(
    bvh: Path, wav: Path, profile: SkeletonProfile, fps: float = 20.0, bands: int = 27
) -> SpeechTake:
    """Read (on the profile's canonical skeleton), resample and align one take; more than one frame of
    length mismatch is an error."""
    motion = read_bvh(bvh)
    profile.check(motion.skeleton, bvh)
    motion = resample(profile.to_canonical(motion), fps)
    audio = log_mel(*read_wav(wav), fps, bands)
    if abs(motion.num_frames - len(audio)) > 1:
        raise WalkdiffError(
            f"audio and motion lengths differ by more than one frame at {fps:g} fps: {bvh} has "
            f"{motion.num_frames} frames ({motion.num_frames / fps:.2f} s), {wav} has {len(audio)} "
            f"({len(audio) / fps:.2f} s)",
            path=bvh,
        )
    frames = min(motion.num_frames, len(audio))  # a one-frame difference is rounding at the end
    return SpeechTake(bvh.stem, bvh, wav, motion.slice(0, frames), audio[:frames])


# ---------------------------------------------------------------- Lightning


class SequenceDataset(Dataset):
    """Training sequences of normalised poses with the normalised audio around them.

    Item: poses (window, D) and audio (past + window + lookahead, M), the audio running from `past`
    frames before the sequence to `lookahead` frames after it (edge frames repeated at a take's ends).
    """

    def __init__(self, parts: list[tuple[str, np.ndarray, np.ndarray, int, int]], window: int, stride: int):
        self.parts = parts  # (take, poses, padded audio, first frame, last frame + 1) per take
        self.window = window
        self.index = [
            (i, start)
            for i, (_, _, _, begin, end) in enumerate(parts)
            for start in range(begin, end - window + 1, stride)
        ]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict:
        part, start = self.index[i]
        take, poses, audio, _, _ = self.parts[part]
        span = audio.shape[0] - poses.shape[0]  # past + lookahead
        return {
            "poses": poses[start : start + self.window],
            "audio": audio[start : start + self.window + span],
            "take": take,
            "start": start,
        }


class SpeechDataModule(WindowLoaders):
    """BVH + WAV takes -> training sequences for DiffMotion.

    Args:
        dataset: folder name under the data root (`zeggs`), or a path (with a slash) to a folder of takes.
        root: data root; default $WALKDIFF_DATA, else ./data.
        fps: motion frame rate (audio features are computed at the same rate).
        joints: joint names to model; default the upper body (see `default_joints`).
        rotation: 'expmap' (the paper) or '6d'.
        bands: mel bands.
        past, lookahead: audio frames before and after the current frame in its control window.
        window: frames per training sequence (120 = 6 s at 20 fps); stride: frames between starts.
        train_fraction: the first part of every take trains, the rest tests.
    """

    def __init__(
        self,
        dataset: str = "zeggs",
        root: str | None = None,
        fps: float = 20.0,
        joints: list[str] | None = None,
        rotation: str = "expmap",
        bands: int = 27,
        past: int = 10,
        lookahead: int = 20,
        window: int = 120,
        stride: int = 10,
        train_fraction: float = 0.8,
        batch_size: int = 16,
        num_workers: int = 0,
        profile: dict | None = None,
    ):
        super().__init__()
        self.save_hyperparameters(logger=False)  # the run logs its config (run_params)
        if rotation not in ROTATIONS:
            raise WalkdiffError(f"data.rotation must be one of {', '.join(ROTATIONS)}, got {rotation!r}")
        if window < 2 or stride < 1 or past < 0 or lookahead < 0:
            raise WalkdiffError(
                f"expected data.window >= 2, stride >= 1, past and lookahead >= 0; got {window}, {stride}, "
                f"{past}, {lookahead}"
            )
        if not 0 < train_fraction < 1:
            raise WalkdiffError(f"data.train_fraction must be in (0, 1), got {train_fraction}")
        # A name is a folder under the data root; anything with a slash is a folder path itself.
        self.folder = Path(dataset).expanduser() if "/" in dataset else dataset_dir(dataset, root)
        if not self.folder.is_dir():
            raise WalkdiffError("data.dataset: folder of takes not found", path=self.folder)
        self.pairs = list_takes(self.folder)
        self.takes: list[SpeechTake] | None = None
        self.normalizer: Normalizer | None = None
        self.audio_normalizer: Normalizer | None = None
        self.neutral: NeutralPose | None = None
        self.datasets: dict[str, SequenceDataset] = {}
        self._profile: SkeletonProfile | None = None

    @property
    def profile(self) -> SkeletonProfile:
        """The takes' skeleton profile, from the first take and the data.profile overrides."""
        if self._profile is None:
            self._profile = SkeletonProfile.detect(read_bvh(self.pairs[0][0]), self.hparams.profile)
        return self._profile

    def load_takes(self) -> list[SpeechTake]:
        if self.takes is None:
            h = self.hparams
            self.takes = [load_take(bvh, wav, self.profile, h.fps, h.bands) for bvh, wav in self.pairs]
        return self.takes

    @property
    def skeleton(self) -> Skeleton:
        """The canonical skeleton the poses are on."""
        return self.profile.canonical_skeleton

    @property
    def joint_names(self) -> list[str]:
        names = self.hparams.joints or default_joints(self.skeleton)
        for name in names:
            if name not in self.skeleton.names:
                raise WalkdiffError(f"data.joints: no joint {name!r} in {self.pairs[0][0]}")
        return list(names)

    @property
    def joint_indices(self) -> list[int]:
        return [self.skeleton.index(n) for n in self.joint_names]

    @property
    def sample_rate(self) -> int | None:
        """The rate of the takes' audio where they all share one (streamed audio must come at it)."""
        rates = {wav_info(wav).samplerate for _, wav in self.pairs}
        return rates.pop() if len(rates) == 1 else None

    @property
    def spec(self) -> SpeechSpec:
        h = self.hparams
        names = self.joint_names
        return SpeechSpec(
            dataset=h.dataset,
            feature_dim=len(names) * ROTATIONS[h.rotation],
            num_joints=len(names),
            window=h.window,
            fps=h.fps,
            joints=tuple(names),
            rotation=h.rotation,
            audio_dim=h.bands,
            past=h.past,
            lookahead=h.lookahead,
            sample_rate=self.sample_rate,
        )

    def split_frames(self, take: SpeechTake, split: str) -> tuple[int, int]:
        """[begin, end) frames of a take in a split ('val' is the test part)."""
        cut = int(round(take.motion.num_frames * self.hparams.train_fraction))
        return (0, cut) if split == "train" else (cut, take.motion.num_frames)

    def poses(self, take: SpeechTake) -> np.ndarray:
        return encode_poses(take.motion, self.joint_indices, self.hparams.rotation)

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        h = self.hparams
        takes = self.load_takes()
        poses = [self.poses(t) for t in takes]
        train = [self.split_frames(t, "train") for t in takes]
        self.normalizer = Normalizer.fit([p[b:e] for p, (b, e) in zip(poses, train)])
        self.audio_normalizer = Normalizer.fit([t.audio[b:e] for t, (b, e) in zip(takes, train)])
        self.neutral = NeutralPose.of([t.motion.slice(b, e) for t, (b, e) in zip(takes, train)])
        for split, stride in (("train", h.stride), ("val", h.window), ("test", h.window)):
            parts = []
            for take, p in zip(takes, poses):
                audio = self.audio_normalizer.normalize(take.audio)
                padded = np.concatenate(
                    [audio[:1].repeat(h.past, 0), audio, audio[-1:].repeat(h.lookahead, 0)]
                )
                begin, end = self.split_frames(take, split)
                parts.append((take.name, self.normalizer.normalize(p), padded, begin, end))
            self.datasets[split] = SequenceDataset(parts, h.window, stride)
            if len(self.datasets[split]) == 0:
                raise WalkdiffError(
                    f"the {split} part of the takes has no {h.window}-frame sequences; shorten data.window"
                )
        log.info(f"speech: {len(self.datasets['train'])} training sequences of {h.window} frames")
