"""The styled generator as one object: load a StyledMotionDiffusion once, then sample or restyle in memory.

`walkdiff.load` returns it for a generator checkpoint, and `walkdiff sample` and `walkdiff transfer`
(styled/commands.py) write what it makes, so a notebook and the commands get the same clips for the same
seed and settings. The windows, samplers and transfer themselves are in styled/generation.py.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError, python_api
from walkdiff.common.memory import SAMPLE_BYTES_PER_FRAME, check_frames
from walkdiff.diffusion import SamplerChoice
from walkdiff.models.pipeline import Generated, Pipeline
from walkdiff.models.style_examples import (
    MATCH_CLIPS,
    StyleExample,
    check_match_clips,
    clip_name,
    example_windows,
    label_code,
    mixed_code,
    parse_style_clips,
)
from walkdiff.models.style_labels import DEFAULT_TRANSITION, StyleTimeline, parse_style, parse_timeline
from walkdiff.models.style_spec import Style
from walkdiff.models.style_statistics import StyleStatistics
from walkdiff.motion.footfix import fix_feet as pinned_feet
from walkdiff.motion.footfix import set_down
from walkdiff.motion.representation import FeatureLayout, decode, encode, start_pose
from walkdiff.motion.skeleton import Motion
from walkdiff.retarget.take import Take
from walkdiff.retarget.target_rig import TargetRig
from walkdiff.styled.edits import CANDIDATES, FILL_SAMPLER, Edits
from walkdiff.styled.generation import (
    Sampling,
    check_finite,
    generate_long,
    load_generator,
    noised_steps,
    resolve_windows,
    restyle,
)
from walkdiff.styled.generation import (
    batch_of as _batch,
)


@dataclass(frozen=True)
class Request:
    """What to make, checked against the model before any work: the style as asked, as conditioning (an
    id, mixing weights or a code) and as a file-name label, the content, the sampler, how windows are
    joined and the rig to play the clips on."""

    spec: Style
    style: torch.Tensor
    label: str
    content_name: str
    content: torch.Tensor
    sampling: Sampling
    overlap: int
    blend: int
    rig: TargetRig | None = None
    examples: tuple[StyleExample, ...] = ()
    timeline: StyleTimeline | None = None

    def record(self) -> dict:
        """The style as a manifest records it."""
        return {
            "style": self.spec.labels,
            "style_clips": [e.record() for e in self.examples],
            "match_clips": self.spec.match if self.examples else None,
        }

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


# The order of a sample manifest's settings.
SAMPLE_SETTINGS = (
    "style", "style_clips", "match_clips", "timeline", "content", "num", "frames", "fps", "sampler", "steps",
    "eta", "guidance", "overlap", "blend", "ground", "fix_feet", "distilled_jumps",
)  # fmt: skip


def root_path_error(source: Motion, result: Motion) -> dict[str, float]:
    """Mean horizontal distance between the two root paths, absolute and relative to the distance walked."""
    a, b = source.root_positions[:, [0, 2]], result.root_positions[:, [0, 2]]
    walked = float(np.linalg.norm(np.diff(a, axis=0), axis=1).sum())
    error = float(np.linalg.norm(a - b, axis=1).mean())
    return {"mean": error, "walked": walked, "relative": error / walked if walked > 0 else float("nan")}


class StyledGenerator(Pipeline, Edits):
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

    @python_api
    def sample(
        self,
        style=None,
        content: str = "walk",
        num: int = 1,
        frames: int = 300,
        seed: int = 0,
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        blend: int | None = None,
        ground: bool = True,
        fix_feet: bool | None = None,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        style_clips=None,
        transition: float = DEFAULT_TRANSITION,
        match_clips: float = MATCH_CLIPS,
        keys=None,
    ) -> Generated:
        """`num` clips of `frames` frames, drawn together as `walkdiff sample` draws them: the same seed
        and settings give the same clips. `style`: a name, a mix ({'angry': 0.7, 'old': 0.3}, or
        'angry:0.7,old:0.3'), a timeline ([(0, 'neutral'), (4, 'old')], ramped over `transition` seconds)
        or a `Style`. `style_clips`: example clips whose style to take, alone or mixed with `style` (paths,
        Motions, Takes or (clip, weight) pairs); `match_clips`: how far their pose statistics are matched
        too (0: their code alone). `sampler`: a name with `steps`, `eta`, `guidance`, or a SamplerChoice.
        `to` (+ `to_map`): a rig to play them on. `fix_feet`: pin feet during contacts (default: where
        clips' statistics are matched). `keys`: poses, root positions or headings the clips pass through
        (a BVH of key poses, 'FILE.bvh@F0,F1,...', a JSON file or a list of dicts: styled/keys.py);
        the style may then be left out. Returns the takes with the settings used (`Generated`)."""
        check_sample_size(num, frames)
        request = self.request(
            style, content, sampler, steps, eta, guidance, overlap, blend, to, to_map, style_clips,
            transition, match_clips, unstyled=keys is not None,
        )  # fmt: skip
        if keys is not None:
            return self.keyed(request, keys, num, frames, seed, ground, fix_feet)
        return self.make(request, num, frames, seed, ground, fix_feet)

    @python_api
    def inbetween(
        self,
        a: Motion | Take | str | os.PathLike,
        b: Motion | Take | str | os.PathLike,
        frames: int,
        style=None,
        place: bool = False,
        fill_only: bool = False,
        content: str = "walk",
        seed: int = 0,
        sampler: str | SamplerChoice | dict = FILL_SAMPLER,
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        fix_feet: bool = True,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
        candidates: int = CANDIDATES,
    ) -> Generated:
        """`frames` frames from the end of clip `a` to the start of clip `b` (Motions, Takes or BVH files on
        the model's skeleton), in `style` (as `sample` takes it; none: the model's own motion, led by the
        clips). B stays where its file puts it, or with `place` where the fill brings it. The take is A,
        the fill and B as one clip (A and B exactly as given), or with `fill_only` the fill alone;
        `extra` holds the fill's frames, the kept frames' error in body heights and the input as one take
        (`source`: A, A's last pose held over the gap, B; what previews show beside). `candidates` fills
        are drawn together and the most typical is kept (1: the first drawn). A sampler given without
        `steps` takes FILL_STEPS (20) here: DPM-Solver++ over 20 steps is the default."""
        request = self.request(
            style, content, sampler, steps, eta, guidance, overlap, None, to, to_map, style_clips,
            match_clips=match_clips, unstyled=True,
        )  # fmt: skip
        return self.fill(request, a, b, frames, seed, place, fill_only, fix_feet, candidates)

    @python_api
    def edit(
        self,
        clip: Motion | Take | str | os.PathLike,
        keep,
        style=None,
        content: str = "walk",
        seed: int = 0,
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        ground: bool = True,
        fix_feet: bool = True,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
    ) -> Generated:
        """`clip` with what `keep` does not name made anew in `style`: `keep` is 'legs', 'upper-body',
        'root' or joint names (text with commas, or a list); the kept joints' rotations (and the root's
        path where the root is kept) come out exactly as given. `extra["kept_error"]`: their largest
        distance from the input, in body heights."""
        request = self.request(
            style, content, sampler, steps, eta, guidance, overlap, None, to, to_map, style_clips,
            match_clips=match_clips, unstyled=True,
        )  # fmt: skip
        return self.edited(request, clip, keep, seed, ground, fix_feet)

    @python_api
    def transfer(
        self,
        motion: Motion | Take | str | os.PathLike,
        style=None,
        content: str = "walk",
        strength: float = 0.6,
        keep_trajectory: bool = False,
        seed: int = 0,
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        blend: int | None = None,
        ground: bool = True,
        fix_feet: bool | None = None,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        style_clips=None,
        match_clips: float = MATCH_CLIPS,
    ) -> Generated:
        """A clip (a Motion, a Take or a BVH file, on the training files' skeleton, any frame rate)
        restyled as `walkdiff transfer` does: noised to `strength` of the schedule and denoised in
        `style` (as `sample` takes it, but one style, no timeline); `keep_trajectory` keeps its root path
        exactly; `to`: a rig to play it on. The result reads as its one take."""
        request = self.request(
            style, content, sampler, steps, eta, guidance, overlap, blend, to, to_map, style_clips,
            match_clips=match_clips,
        )  # fmt: skip
        result = self.restyle(request, motion, strength, keep_trajectory, seed, ground, fix_feet)
        for note in result.warnings:
            warnings.warn(note, stacklevel=3)
        return result

    @python_api
    def request(
        self,
        style=None,
        content: str = "walk",
        sampler: str | SamplerChoice | dict = "ddpm",
        steps: int | None = None,
        eta: float = 0.0,
        guidance: float = 1.0,
        overlap: int | None = None,
        blend: int | None = None,
        to: TargetRig | str | os.PathLike | Motion | None = None,
        to_map=None,
        style_clips=None,
        transition: float = DEFAULT_TRANSITION,
        match_clips: float = MATCH_CLIPS,
        unstyled: bool = False,
    ) -> Request:
        """What `sample` or `transfer` will make, checked against the model before any work, or a
        WalkdiffError naming what is wrong. Example clips give their code, and their statistics matched at
        `match_clips` times their share of the weight (a `style` label weighs 1). `unstyled`: no style
        may be given (the edits: the model's unconditional motion, led by the kept parts)."""
        spec = Style.of(style, style_clips, match_clips, transition)
        sampling = Sampling.of(sampler, steps, eta, guidance)
        check_match_clips(spec.match)
        content_id = self.model.label_ids([content], "content")[0]
        overlap, blend = resolve_windows(self.model.spec["window"], overlap, blend)
        rig = TargetRig.of(to, to_map)
        if spec.labels is None and not spec.clips:
            if not unstyled:
                raise WalkdiffError(
                    "no style given: pass --style NAME[,...], --style-clip FILE[,...] or both"
                )
            null = torch.tensor(self.model.ema.module.style.null_id, device=self.model.device)
            return Request(spec, null, "unstyled", content, content_id, sampling, overlap, blend, rig)
        timeline = None if spec.labels is None else parse_timeline(self.model, spec.labels, spec.transition)
        if timeline is not None:
            if spec.clips:
                raise WalkdiffError(
                    "--style-clip: not in a timeline; give the timeline's keys as --style names"
                )
            for weights in timeline.weights:
                self.check_trained(weights)
            return Request(
                spec, timeline.at(0.0), timeline.label, content, content_id, sampling, overlap, blend, rig,
                (), timeline,
            )  # fmt: skip
        if spec.labels is not None:
            style_label, label = parse_style(self.model, spec.labels)
            self.check_trained(style_label)
        examples: tuple[StyleExample, ...] = ()
        if spec.clips:
            self.model.style_code(None)  # a model without a style encoder says so before any clip is read
            weighted, statistics, examples = self.examples(spec.clips)
            clips_weight = sum(w for _, w in weighted)
            if spec.labels is not None:
                weighted.insert(0, (label_code(self.model, style_label), 1.0))
            style_label = mixed_code(weighted)
            if spec.match > 0:
                share = clips_weight / sum(w for _, w in weighted)
                sampling = replace(sampling, match=StyleStatistics.mixed(statistics, spec.match * share))
            names = [f"clip-{Path(e.source).stem}" for e in examples]
            label = "+".join(([label] if spec.labels is not None else []) + names)
        return Request(spec, style_label, label, content, content_id, sampling, overlap, blend, rig, examples)

    def make(
        self, request: Request, num: int, frames: int, seed: int = 0, ground: bool = True, fix_feet=None
    ) -> Generated:
        """`sample`'s work on a checked request: the takes and the settings a manifest records."""
        started = time.perf_counter()
        clips = self.generate(request, num, frames, seed, ground, fix_feet)
        generated = time.perf_counter() - started
        settings = {
            **request.record(),
            "timeline": None if request.timeline is None else request.timeline.record(),
            "content": request.content_name,
            "num": num,
            "frames": frames,
            "fps": self.fps,
            **request.sampling.record(),
            "overlap": request.overlap,
            "blend": request.blend,
            "ground": ground,
            "fix_feet": request.pins_feet(fix_feet),
            "distilled_jumps": self.model.jumps(
                request.sampling.name, request.sampling.steps, request.sampling.eta
            ) is not None,
        }  # fmt: skip
        settings = {key: settings[key] for key in SAMPLE_SETTINGS}
        takes = [self.take(clip, request.rig) for clip in clips]
        timing = {
            "generate_s": round(generated, 3),
            "generated_frames_per_s": round(num * frames / generated, 1),
        }
        return Generated(
            takes,
            settings,
            timing,
            seed=seed,
            rig=request.rig,
            label=request.label,
            extra={"timeline": request.timeline},
        )

    def restyle(
        self,
        request: Request,
        motion: Motion | Take | str | os.PathLike,
        strength: float = 0.6,
        keep_trajectory: bool = False,
        seed: int = 0,
        ground: bool = True,
        fix_feet=None,
    ) -> Generated:
        """`transfer`'s work on a checked request: the restyled take, the source on the same rig
        (`extra["source"]`), how far the root path moved, and a warning for a clip shorter than a window."""
        if request.timeline is not None:
            raise WalkdiffError("--style: a timeline (STYLE@SECONDS) is for sample; transfer takes one style")
        noised_steps(self.model, strength, request.sampling)  # a bad strength fails before any warning
        source = self.source(motion)
        short = self.window_note(source, motion if isinstance(motion, str | os.PathLike) else "the clip")
        started = time.perf_counter()
        result = self.restyled(request, source, strength, keep_trajectory, seed, ground, fix_feet)
        elapsed = time.perf_counter() - started
        settings = {
            **request.record(),
            "content": request.content_name,
            "strength": strength,
            "keep_trajectory": keep_trajectory,
            "frames": source.num_frames,
            "fps": self.fps,
            **request.sampling.record(),
            "overlap": request.overlap,
            "blend": request.blend,
            "ground": ground,
            "fix_feet": request.pins_feet(fix_feet),
        }
        source_take, moved = self.take(source, request.rig), root_path_error(source, result)
        extra = {"source": source_take, "root_path_error": moved}
        return Generated(
            [self.take(result, request.rig)], settings, {"restyle_s": round(elapsed, 3)},
            [] if short is None else [short], seed=seed, rig=request.rig, label=request.label, extra=extra,
        )  # fmt: skip

    def examples(self, style_clips) -> tuple[list, list, tuple[StyleExample, ...]]:
        """Each example clip's (code, weight) and (statistics, weight), and what the manifest records."""
        weighted, statistics, examples = [], [], []
        for clip, weight in parse_style_clips(style_clips):
            where = clip_name(clip)
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
            spec = model.profile.contacts
            labels = raw[:, FeatureLayout(model.skeleton.num_joints).contacts]
            motion = pinned_feet(motion, set_down(motion, labels, spec, model.floor_heights), spec)
        return motion
