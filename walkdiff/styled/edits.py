"""The edits' work behind `StyledGenerator.inbetween`, `sample(keys=...)` and `edit` (styled/pipeline.py):
a checked request and the user's clips or keys turned into a constraint (styled/editing.py), sampled, and
decoded into takes with the kept parts exactly as given."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress, step_hook
from walkdiff.models.pipeline import Generated
from walkdiff.motion.representation import FeatureLayout
from walkdiff.motion.skeleton import Motion
from walkdiff.styled import editing
from walkdiff.styled import keys as keyframes
from walkdiff.styled.generation import batch_of as _batch
from walkdiff.styled.generation import check_finite

# An in-between's sampler: DPM-Solver++ over 20 steps, 8 fills drawn together and the most typical kept
# (editing.most_typical). On held-out clips this puts the 45-frame fill ahead of interpolation on L2P and
# NPSS in about the time of one fill of DDPM's 100 steps, which alone is level on L2P (docs/editing.md,
# "Measured", "At the defaults"). cli/options.py repeats them (a test keeps them equal).
FILL_SAMPLER = "dpmpp"
FILL_STEPS = 20
CANDIDATES = 8


def fill_steps(sampler: str, steps: int | None) -> int | None:
    """An in-between's steps: FILL_STEPS where a sampler that takes steps is given without them."""
    return FILL_STEPS if steps is None and sampler != "ddpm" else steps


class Edits:
    """What `StyledGenerator` does for the edits, on a request it has checked (`request`)."""

    resample = 0  # RePaint resampling of the edits' sampling (editing.masked_sample)
    guide = 1.0  # in-betweens: reconstruction guidance of the fill (editing.reconstruction_guided)

    def fill(
        self, request, a, b, frames: int, seed: int = 0, place: bool = False,
        fill_only: bool = False, fix_feet: bool = True, candidates: int = CANDIDATES,
    ) -> Generated:  # fmt: skip
        """`inbetween`'s work on a checked request."""
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise WalkdiffError(f"--frames: the gap must be at least 1 frame, got {frames!r}")
        if not isinstance(candidates, int) or isinstance(candidates, bool) or candidates < 1:
            raise WalkdiffError(f"--candidates: expected a whole number of fills >= 1, got {candidates!r}")
        clip_a, clip_b = self.source(a, "A", 1), self.source(b, "B", 1)
        steps = fill_steps(request.sampling.name, request.sampling.steps)
        request = replace(request, sampling=replace(request.sampling, steps=steps))
        model, profile = self.model, self.model.profile
        constraint, before, after = editing.inbetween_constraint(
            clip_a, clip_b, frames, profile, model.spec["window"], place
        )
        end = before + frames + after
        held = np.zeros(constraint.frames, bool)
        held[:before] = held[before + frames : end] = True
        started = time.perf_counter()
        raws = self._masked(request, constraint, seed, candidates, self.guide)
        pick = 0
        if candidates > 1:
            pick = editing.most_typical(raws[:, :end], constraint, held[:end], model.skeleton, self.fps)
        raw = raws[pick]
        if place:  # B turned and moved to where the fill ends
            clip_b = editing.turned(clip_b, profile, *editing.root_at(raw, constraint, before + frames))
        kept = _joined(
            [clip_a.slice(clip_a.num_frames - before, clip_a.num_frames), frames, clip_b.slice(0, after)]
            + ([constraint.frames - end] if constraint.frames > end else [])
        )
        motion = editing.finish(raw, constraint, model.skeleton, profile, self.fps, kept, held, [], fix_feet)
        check_finite([motion], request.sampling)
        gap = motion.slice(before, before + frames)
        whole = _joined([clip_a, gap, clip_b])
        result = gap if fill_only else whole
        elapsed = time.perf_counter() - started
        take = self.take(result, request.rig)
        made = whole if request.rig is not None or fill_only else take.canonical()
        error = editing.kept_error(
            made, _joined([clip_a, frames, clip_b]), _held(clip_a.num_frames, frames, clip_b.num_frames), [],
            profile.body_height,
        )  # fmt: skip
        settings = {
            **request.record(), "content": request.content_name, "frames": frames, "place": place,
            "fill_only": fill_only, "context": [before, after], "fps": self.fps, **request.sampling.record(),
            "overlap": request.overlap, "fix_feet": fix_feet, "candidates": candidates,
        }  # fmt: skip
        fill = (0, frames) if fill_only else (clip_a.num_frames, clip_a.num_frames + frames)
        last = clip_a.slice(clip_a.num_frames - 1, clip_a.num_frames)
        held_gap = replace(
            last, rotations=last.rotations.repeat(frames, 0), positions=last.positions.repeat(frames, 0)
        )
        source = _joined([clip_a, held_gap, clip_b])  # the input, A's last pose held over the gap
        extra = {"fill": fill, "kept_error": error, "source": self.take(source, request.rig)}
        return Generated(
            [take], settings, {"generate_s": round(elapsed, 3)}, seed=seed, rig=request.rig,
            label=request.label, extra=extra,
        )  # fmt: skip

    def keyed(
        self, request, keys, num: int, frames: int, seed: int = 0, ground: bool = True, fix_feet=None
    ) -> Generated:
        """`sample(keys=...)`'s work on a checked request."""
        if request.timeline is not None:
            raise WalkdiffError("--keys: not with a style timeline; give one style (or a mix)")
        profile = self.model.profile
        found = keyframes.read_keys(keys, profile, frames)
        constraint = keyframes.keys_constraint(found, frames, profile)
        started = time.perf_counter()
        raws = self._masked(request, constraint, seed, num)
        layout = FeatureLayout(self.model.skeleton.num_joints)
        if ground and not constraint.mask[:, layout.root_height].any():  # no keyed pose sets the height
            raws = self.model.ground(raws.astype(np.float32)).astype(np.float64)
        held = constraint.mask[:, layout.rotations].all(1)  # frames of a keyed pose
        kept = _posed(found, frames, self.model.skeleton)
        pin = request.pins_feet(fix_feet)
        clips = [
            editing.finish(raw, constraint, self.model.skeleton, profile, self.fps, kept, held, [], pin)
            for raw in raws
        ]
        check_finite(clips, request.sampling)
        elapsed = time.perf_counter() - started
        takes = [self.take(clip, request.rig) for clip in clips]
        made = [t.canonical() if request.rig is None else c for t, c in zip(takes, clips, strict=True)]
        error = max(editing.kept_error(m, kept, held, [], profile.body_height) for m in made)
        passed = _root_key_error(made, constraint.keys, profile)
        settings = {
            **request.record(), "content": request.content_name, "num": num, "frames": frames,
            "fps": self.fps,
            "keys": [{"frame": k.frame, "pose": k.pose is not None, "root": k.position is not None,
                      "heading": k.heading is not None} for k in found],
            **request.sampling.record(), "overlap": request.overlap, "ground": ground, "fix_feet": pin,
        }  # fmt: skip
        extra = {"kept_error": error, "root_key_error": passed}
        timing = {"generate_s": round(elapsed, 3)}
        return Generated(
            takes, settings, timing, seed=seed, rig=request.rig, label=request.label, extra=extra
        )

    def edited(
        self, request, clip, keep, seed: int = 0, ground: bool = True, fix_feet: bool = True
    ) -> Generated:
        """`edit`'s work on a checked request."""
        if request.timeline is not None:
            raise WalkdiffError("--style: a timeline (STYLE@SECONDS) is for sample; edit takes one style")
        model, profile = self.model, self.model.profile
        joints = editing.kept_joints(keep, model.skeleton)
        source = self.source(clip, "edit")
        constraint = editing.edit_constraint(source, joints, profile)
        started = time.perf_counter()
        raw = self._masked(request, constraint, seed, 1)
        if ground and 0 not in joints:
            raw = model.ground(raw.astype(np.float32)).astype(np.float64)
        feet = {model.skeleton.index(n) for n in profile.contacts.joints}
        pin = fix_feet and not feet <= set(joints)  # kept feet are the input's own
        none = np.zeros(source.num_frames, bool)
        motion = editing.finish(
            raw[0], constraint, model.skeleton, profile, self.fps, source, none, joints, pin
        )
        check_finite([motion], request.sampling)
        elapsed = time.perf_counter() - started
        take = self.take(motion, request.rig)
        made = take.canonical() if request.rig is None else motion
        error = editing.kept_error(made, source, none, joints, profile.body_height)
        settings = {
            **request.record(), "content": request.content_name,
            "keep": keep if isinstance(keep, str) else list(keep),
            "kept_joints": [model.skeleton.names[j] for j in joints], "frames": source.num_frames,
            "fps": self.fps, **request.sampling.record(), "overlap": request.overlap, "ground": ground,
            "fix_feet": pin,
        }  # fmt: skip
        extra = {"kept_error": error, "kept_joints": joints, "source": self.take(source, request.rig)}
        return Generated(
            [take], settings, {"generate_s": round(elapsed, 3)}, seed=seed, rig=request.rig,
            label=request.label, extra=extra,
        )  # fmt: skip

    def _masked(self, request, constraint, seed: int, num: int, guide: float = 0.0) -> np.ndarray:
        """Raw features (num, F, D) of a constraint, drawn from `seed` (editing.masked_sample)."""
        generator = torch.Generator(device=self.model.device).manual_seed(seed)
        bar = progress(desc="sampling", unit="step")
        with bar:
            return editing.masked_sample(
                self.model, constraint, _batch(request.style, num), _batch(request.content, num),
                request.sampling, generator, request.overlap, step_hook(bar, 1), self.resample,
                guide,
            )  # fmt: skip


def _joined(parts: list) -> Motion:
    """Canonical clips (and frame counts: identity frames at the origin, overwritten later) as one."""
    clips = [p for p in parts if isinstance(p, Motion)]
    skeleton, frame_time = clips[0].skeleton, clips[0].frame_time
    rotations, positions = [], []
    for part in parts:
        if isinstance(part, Motion):
            rotations.append(part.rotations)
            positions.append(part.positions)
        else:
            rotations.append(np.broadcast_to(np.eye(3), (part, skeleton.num_joints, 3, 3)))
            positions.append(np.broadcast_to(skeleton.offsets, (part, skeleton.num_joints, 3)))
    return Motion(skeleton, np.concatenate(rotations), np.concatenate(positions), frame_time)


def _held(*lengths: int) -> np.ndarray:
    """(F,) booleans of joined parts: the first and last part held, the middle (a gap) not."""
    a, gap, b = lengths
    return np.concatenate([np.ones(a, bool), np.zeros(gap, bool), np.ones(b, bool)])


def _posed(keys: list, frames: int, skeleton) -> Motion:
    """A clip of `frames` frames holding each keyed pose at its frame (the others: identity frames)."""
    rotations = np.broadcast_to(np.eye(3), (frames, skeleton.num_joints, 3, 3)).copy()
    positions = np.broadcast_to(skeleton.offsets, (frames, skeleton.num_joints, 3)).copy()
    frame_time = 1.0
    for key in keys:
        if key.pose is not None:
            rotations[key.frame], positions[key.frame] = key.pose.rotations[0], key.pose.positions[0]
            frame_time = key.pose.frame_time
    return Motion(skeleton, rotations, positions, frame_time)


def _root_key_error(clips: list[Motion], keys: list, profile) -> float:
    """Largest distance (body heights) between a root key's ground position and the clips' root there,
    after the first key (which places the clip)."""
    placed = [k for k in keys if k.position is not None]
    if len(placed) < 2:
        return 0.0
    errors = [
        np.linalg.norm(clip.root_positions[k.frame, [0, 2]] - np.asarray(k.position))
        for clip in clips
        for k in placed
    ]
    return float(max(errors)) / profile.body_height
