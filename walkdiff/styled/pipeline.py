"""The styled generator as one object: load a StyledMotionDiffusion once, then sample or restyle in memory.

`walkdiff.load` returns it for a generator checkpoint, and `walkdiff sample` and `walkdiff transfer`
(styled/commands.py) write what it makes, so a notebook and the commands get the same clips for the same
seed and settings. The windows, samplers and transfer themselves are in styled/generation.py.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.memory import SAMPLE_BYTES_PER_FRAME, check_frames
from walkdiff.models.pipeline import Pipeline
from walkdiff.models.style_examples import (
    MATCH_CLIPS,
    StyleExample,
    check_match_clips,
    example_windows,
    label_code,
    mixed_code,
    parse_style_clips,
)
from walkdiff.models.style_labels import DEFAULT_TRANSITION, StyleTimeline, parse_style, parse_timeline
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.footfix import fix_feet as pinned_feet
from walkdiff.motion.representation import FeatureLayout, decode, encode, start_pose
from walkdiff.motion.skeleton import Motion
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig
from walkdiff.styled.generation import (
    Sampling,
    generate_long,
    load_generator,
    noised_steps,
    resolve_windows,
    restyle,
)


@dataclass(frozen=True)
class Request:
    """What to make, checked against the model before any work: the style (an id, or mixing weights) and
    its file-name label, the content id, the sampler and how windows are joined."""

    style: torch.Tensor
    label: str
    content: torch.Tensor
    sampling: Sampling
    overlap: int
    blend: int
    examples: tuple[StyleExample, ...] = ()
    timeline: StyleTimeline | None = None

    def pins_feet(self, fix_feet: bool | None) -> bool:
        """Whether feet are pinned during contacts: as asked, or by default where example clips' statistics
        are matched, which moves each channel on its own and so lets the planted feet slide."""
        return self.sampling.match is not None if fix_feet is None else fix_feet


def check_sample_size(num: int, frames: int) -> None:
    """Refuse no clips, and clips too long for memory, before any work (`walkdiff sample`: before the
    model loads)."""
    if num < 1:
        raise WalkdiffError(f"--num must be at least 1, got {num}")
    if frames >= 1:  # window_plan names a bad --frames
        check_frames("--frames", frames, SAMPLE_BYTES_PER_FRAME, num)


def check_finite(clips: list[Motion], sampling: Sampling) -> None:
    """Refuse clips with NaN or infinite values, naming the setting that made them: no such clip is ever
    returned or written (a BVH of NaN reads as motion in no program)."""
    bad = [
        i
        for i, clip in enumerate(clips)
        if not (np.isfinite(clip.rotations).all() and np.isfinite(clip.positions).all())
    ]
    if not bad:
        return
    which = (
        f"clip {bad[0]}" if len(clips) == 1 else f"{len(bad)} of {len(clips)} clips, the first clip {bad[0]}"
    )
    if sampling.guidance != 1:
        raise WalkdiffError(
            f"--guidance {sampling.guidance:g} made non-finite motion (NaN or infinite values in {which}); "
            "use a lower guidance (1: none; a few at most is useful)"
        )
    raise WalkdiffError(
        f"the model made non-finite motion (NaN or infinite values in {which}, sampler {sampling.sampler}): "
        "its network may have diverged in training; try another checkpoint"
    )


def _batch(labels: torch.Tensor, count: int) -> torch.Tensor:
    """One style id () or mixing vector (S,), or one content id, repeated for a batch."""
    return labels.expand(count, *labels.shape).clone()


class StyledGenerator(Pipeline):
    """A trained StyledMotionDiffusion: `sample` makes styled motion of any length, `transfer` restyles a
    clip; both return `Take`s on the training files' skeleton and write nothing."""

    @classmethod
    def load(cls, ckpt: str | Path, device: str = "cpu") -> StyledGenerator:
        return cls(load_generator(ckpt, device))

    @property
    def styles(self) -> tuple[str, ...]:
        return tuple(self.model.spec["styles"])

    @property
    def contents(self) -> tuple[str, ...]:
        return tuple(self.model.spec["contents"])

    def sample(
        self,
        style: str | None = None,
        content: str = "walk",
        num: int = 1,
        frames: int = 300,
        seed: int = 0,
        sampler: str = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        blend: int | None = None,
        ground: bool = True,
        fix_feet: bool | None = None,
        to: TargetRig | str | os.PathLike | None = None,
        style_clips=None,
        transition: float = DEFAULT_TRANSITION,
        match_clips: float = MATCH_CLIPS,
    ) -> list[Take]:
        """`num` clips of `frames` frames in `style` (a name, or a mix such as 'angry:0.7,old:0.3'), drawn
        together as `walkdiff sample` draws them: the same seed and settings give the same clips. `to`: a
        rig to play them on (`Take.retarget`). `style_clips`: example clips whose style to take, alone or
        mixed with `style` ('a.bvh:0.7,b.bvh', or a list of paths, Motions or (clip, weight) pairs). A
        timeline `style` ('neutral@0,old@4s') changes style over time, ramped over `transition` seconds.
        `match_clips`: how far the clips' pose statistics are matched too (0: their code alone).
        `fix_feet`: pin feet during contacts (default: where clips' statistics are matched)."""
        check_sample_size(num, frames)
        sampling = Sampling(sampler, steps, eta, guidance)
        request = self.request(style, content, sampling, overlap, blend, style_clips, transition, match_clips)
        rig = TargetRig.of(to)  # a wrong rig is said before any sampling
        clips = self.generate(request, num, frames, seed, ground, fix_feet)
        return [self.take(clip, rig) for clip in clips]

    def transfer(
        self,
        motion: Motion | Take | str | os.PathLike,
        style: str | None = None,
        content: str = "walk",
        strength: float = 0.6,
        keep_trajectory: bool = False,
        seed: int = 0,
        sampler: str = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        blend: int | None = None,
        ground: bool = True,
        fix_feet: bool | None = None,
        to: TargetRig | str | os.PathLike | None = None,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
    ) -> Take:
        """A clip (a Motion, a Take or a BVH file, on the training files' skeleton, any frame rate)
        restyled as `walkdiff transfer` does: noised to `strength` of the schedule and denoised in
        `style`; `keep_trajectory` keeps its root path exactly; `to`: a rig to play it on."""
        rig = TargetRig.of(to)
        sampling = Sampling(sampler, steps, eta, guidance)
        request = self.request(style, content, sampling, overlap, blend, style_clips, match_clips=match_clips)
        if request.timeline is not None:
            raise WalkdiffError("--style: a timeline (STYLE@SECONDS) is for sample; transfer takes one style")
        noised_steps(self.model, strength, request.sampling)  # a bad strength fails before any warning
        source = self.source(motion)
        short = self.window_note(source, motion if isinstance(motion, str | os.PathLike) else "the clip")
        if short is not None:
            warnings.warn(short, stacklevel=2)
        result = self.restyled(request, source, strength, keep_trajectory, seed, ground, fix_feet)
        return self.take(result, rig)

    def request(
        self,
        style: str | None,
        content: str,
        sampling: Sampling,
        overlap: int | None,
        blend: int | None,
        style_clips=None,
        transition: float = DEFAULT_TRANSITION,
        match_clips: float = MATCH_CLIPS,
    ) -> Request:
        """The labels and windows of a sample or transfer, or a WalkdiffError naming what is wrong. Example
        clips give their code, and their statistics matched at `match_clips` times their share of the
        weight (a --style label weighs 1)."""
        check_match_clips(match_clips)
        if style is None and not style_clips:
            raise WalkdiffError("no style given: pass --style NAME[,...], --style-clip FILE[,...] or both")
        content_id = self.model.label_ids([content], "content")[0]
        overlap, blend = resolve_windows(self.model.spec["window"], overlap, blend)
        examples: tuple[StyleExample, ...] = ()
        timeline = None if style is None else parse_timeline(self.model, style, transition)
        if timeline is not None:
            if style_clips:
                raise WalkdiffError(
                    "--style-clip: not in a timeline; give the timeline's keys as --style names"
                )
            for weights in timeline.weights:
                self.check_trained(weights)
            return Request(
                timeline.at(0.0), timeline.label, content_id, sampling, overlap, blend, (), timeline
            )
        if style is not None:
            style_label, label = parse_style(self.model, style)
            self.check_trained(style_label)
        if style_clips:
            self.model.style_code(None)  # a model without a style encoder says so before any clip is read
            weighted, statistics, examples = self.examples(style_clips)
            clips_weight = sum(w for _, w in weighted)
            if style is not None:
                weighted.insert(0, (label_code(self.model, style_label), 1.0))
            style_label = mixed_code(weighted)
            if match_clips > 0:
                share = clips_weight / sum(w for _, w in weighted)
                sampling = replace(sampling, match=StyleStatistics.mixed(statistics, match_clips * share))
            names = [e.source for e in examples]
            label = "+".join(([label] if style is not None else []) + [f"clip-{Path(n).stem}" for n in names])
        return Request(style_label, label, content_id, sampling, overlap, blend, examples)

    def examples(self, style_clips) -> tuple[list, list, tuple[StyleExample, ...]]:
        """Each example clip's (code, weight) and (statistics, weight), and what the manifest records."""
        weighted, statistics, examples = [], [], []
        for clip, weight in parse_style_clips(style_clips):
            where = str(clip) if isinstance(clip, str | os.PathLike) else "the example clip"
            windows = example_windows(self.model, self.source(clip, "--style-clip"), where)
            code = self.model.style_code(windows)
            weighted.append((code, weight))
            statistics.append((StyleStatistics.of(windows), weight))
            examples.append(StyleExample(where, weight, tuple(code.tolist())))
        return weighted, statistics, tuple(examples)

    def check_trained(self, style: torch.Tensor) -> None:
        """A style with no stored code (left out of training, data.leave_out_styles) is refused by name."""
        codes = getattr(self.model.ema.module.style, "codes", None)
        if codes is None:
            return
        used = [style.item()] if not style.is_floating_point() else style.nonzero()[:, 0].tolist()
        missing = [self.styles[i] for i in used if not codes[i].any()]
        if missing:
            raise WalkdiffError(
                f"--style {', '.join(missing)}: this model has no code for it (no training clip of that "
                "style, or data.leave_out_styles left it out); give an example clip: --style-clip FILE"
            )

    def window_note(self, source: Motion, where: str | os.PathLike) -> str | None:
        """What a transfer of a clip shorter than the model's window should say: it is restyled as one
        window of its own length, shorter than any the model was trained on. None for longer clips."""
        window, frames = self.model.spec["window"], source.num_frames
        if frames >= window:
            return None
        return (
            f"{where}: {frames} frames at the model's {self.fps:g} fps ({frames / self.fps:.2f} s), shorter "
            f"than its {window}-frame window ({window / self.fps:.2f} s): restyled as one {frames}-frame "
            f"window, shorter than any it was trained on, so the style may come out weak (give at least "
            f"{window / self.fps:.2f} s of motion)"
        )

    def generate(
        self, request: Request, num: int, frames: int, seed: int, ground: bool, fix_feet: bool | None
    ) -> list[Motion]:
        """`num` canonical clips of `frames` frames, drawn as one batch from `seed`."""
        model = self.model
        generator = torch.Generator(device=model.device).manual_seed(seed)
        style_at = None
        if request.timeline is not None:
            request.timeline.check_length(frames / self.fps)
            timeline, fps = request.timeline, self.fps
            style_at = lambda start, stop: _batch(timeline.at((start + stop - 1) / 2 / fps), num)  # noqa: E731
        x = generate_long(
            model, _batch(request.style, num), _batch(request.content, num), frames, request.sampling,
            generator, request.overlap, request.blend, style_at,
        )  # fmt: skip
        pinned = request.pins_feet(fix_feet)
        clips = [self._decoded(raw, None, pinned) for raw in model.to_raw(x, ground)]
        check_finite(clips, request.sampling)
        return clips

    def restyled(
        self,
        request: Request,
        source: Motion,
        strength: float,
        keep_trajectory: bool,
        seed: int,
        ground: bool,
        fix_feet: bool | None,
    ) -> Motion:
        """A canonical clip (from `source`) restyled, placed where the source starts."""
        model = self.model
        features = model.normalizer.normalize(torch.from_numpy(encode(source, model.profile)))[None]
        generator = torch.Generator(device=model.device).manual_seed(seed)
        x = restyle(
            model, features, _batch(request.style, 1), _batch(request.content, 1), strength, request.sampling,
            generator, keep_trajectory, request.overlap, request.blend,
        )  # fmt: skip
        start = start_pose(source, model.profile)
        result = self._decoded(model.to_raw(x, ground)[0], start, request.pins_feet(fix_feet))
        check_finite([result], request.sampling)
        return result

    def _decoded(self, raw: np.ndarray, start: tuple[np.ndarray, float] | None, fix_feet: bool) -> Motion:
        """Features in data units (F, D) -> a canonical clip, feet pinned during contacts if asked."""
        model = self.model
        position, heading = start if start is not None else (None, 0.0)
        motion = decode(raw, model.skeleton, 1.0 / self.fps, position, heading)
        if fix_feet:
            contacts = raw[:, FeatureLayout(model.skeleton.num_joints).contacts]
            motion = pinned_feet(motion, contacts, model.profile.contacts)
        return motion
