"""Editing motion with the window GAN-DDPM: in-betweening, keyframes and partial-body edits.

All three are one masked sampling in feature space. A `Constraint` says, per frame and feature channel,
what is known (the frames of the clips around a gap, the channels of a keyed pose, the channels of the
joints an edit keeps) and where the root must pass (`RootKey`: a position on the ground and a heading at
a frame). Sampling then works as the long-motion sampler's inpainting does, generalised:

- the known channels are replaced at every denoising step by the known values noised to that step's
  level (MDM's in-betweening and editing), and put back exactly at the end; in-betweens are also
  reconstruction-guided (Ho et al. 2022, `reconstruction_guided`): replacement shows the network the
  known frames only through noise, so a long fill drifts from B; the guidance moves the made part's
  clean estimate at every step toward what makes the network's estimate of the known frames agree;
- a sequence longer than one window is denoised as overlapping windows *at every step* (their outputs
  averaged with tent weights where they overlap), so a gap of any length sees both of its ends at once;
- the root passes its keys by projection: features hold root velocities, so where a clip ends up is a sum
  over the frames before. At every step the clean estimate's free velocities are moved by the least
  change (the same share per free frame) that makes their sum reach the next key: first the heading
  turns, then the ground steps. The same projection is applied once more, exactly, to the result.

The result is decoded and the kept parts are overwritten in data space with the input's own rotations and
root positions, so they come out as given (to float precision), and the feet of the made frames are
pinned during contacts with the kept ones held (motion/footfix.py). styled/pipeline.py puts this behind
`inbetween`, `sample(keys=...)` and `edit`; styled/edit_commands.py writes their files.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.diffusion import run_steps
from walkdiff.models.style_statistics import moved_output
from walkdiff.motion.footfix import fix_feet
from walkdiff.motion.humanoid import humanoid_map, path_between
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.posed_frames import subtree
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import (
    FeatureLayout,
    contact_state,
    decode,
    encode,
    root_trajectory,
    start_pose,
    yaw_matrix,
)
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.styled.generation import Sampling, window_plan

KEEP_GROUPS = ("legs", "upper-body", "root")


@dataclass(frozen=True)
class RootKey:
    """Where the root is at `frame`: its ground position (x, z, canonical axes) and heading (radians),
    either or both."""

    frame: int
    position: tuple[float, float] | None = None
    heading: float | None = None


@dataclass
class Constraint:
    """What an edited clip keeps: raw feature values (F, D) where `mask` (F, D) is set, the root keys,
    and where the clip starts when no key places it (position (x, z), heading)."""

    known: np.ndarray
    mask: np.ndarray
    keys: list[RootKey] = field(default_factory=list)
    start: tuple[np.ndarray, float] = (np.zeros(2), 0.0)

    @property
    def frames(self) -> int:
        return self.known.shape[0]

    def free_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """(F,) booleans: frames whose ground step, and whose turn, the sampler makes."""
        layout = FeatureLayout.from_dim(self.known.shape[1])
        return ~self.mask[:, layout.root_vel].any(1), ~self.mask[:, layout.heading_vel].any(1)


# ---------------------------------------------------------------- the root through its keys


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.pi - torch.remainder(torch.pi - angle, 2 * torch.pi)


def project_root(raw: torch.Tensor, keys: list[RootKey], free_step: np.ndarray, free_turn: np.ndarray):
    """Raw features (B, F, D) whose free root velocities are moved, by the same share per free frame
    between two keys, so that the decoded root passes every key (relative to the first: `placement`
    puts the first in place). Returns the moved features; frames with nothing free between two keys
    are left as they are."""
    if len(keys) < 2:
        return raw
    layout = FeatureLayout.from_dim(raw.shape[-1])
    out = raw.clone()
    turn = out[..., layout.heading_vel.start]  # (B, F), a view
    headed = [k for k in keys if k.heading is not None]
    for a, b in zip(headed, headed[1:], strict=False):
        free = torch.from_numpy(free_turn[a.frame : b.frame])
        if free.any():
            made = turn[:, a.frame : b.frame].sum(-1)
            change = _wrap(torch.as_tensor(b.heading - a.heading, dtype=raw.dtype) - made)
            turn[:, a.frame : b.frame] += change[:, None] * free.to(raw.dtype) / free.sum()
    placed = [k for k in keys if k.position is not None]
    if len(placed) < 2:
        return out
    heading, _ = root_trajectory(out, None, placement_heading(out, keys))
    step = out[..., layout.root_vel]  # (B, F, 2) in each frame's heading frame, a view
    for a, b in zip(placed, placed[1:], strict=False):
        free = torch.from_numpy(free_step[a.frame : b.frame])
        if not free.any():
            continue
        turns = yaw_matrix(heading[:, a.frame : b.frame])  # (B, n, 3, 3)
        local = torch.stack([step[:, a.frame : b.frame, 0], 0 * step[:, a.frame : b.frame, 0],
                             step[:, a.frame : b.frame, 1]], -1)  # fmt: skip
        made = (turns @ local[..., None])[..., 0].sum(1)[:, [0, 2]]  # (B, 2)
        wanted = torch.as_tensor(np.subtract(b.position, a.position), dtype=raw.dtype)
        share = (wanted - made) / free.sum()  # (B, 2) world
        world = torch.stack([share[:, 0], 0 * share[:, 0], share[:, 1]], -1)[:, None, :, None]
        moved = (turns.transpose(-1, -2) @ world)[..., 0]  # (B, n, 3) in each frame's heading frame
        step[:, a.frame : b.frame] += moved[..., [0, 2]] * free.to(raw.dtype)[None, :, None]
    return out


def placement_heading(raw: torch.Tensor, keys: list[RootKey]) -> torch.Tensor:
    """(B,) heading of frame 0 that turns the clip onto its first heading key (0 without one)."""
    headed = [k for k in keys if k.heading is not None]
    if not headed:
        return torch.zeros(raw.shape[0], dtype=raw.dtype)
    layout = FeatureLayout.from_dim(raw.shape[-1])
    made = raw[:, : headed[0].frame, layout.heading_vel.start].sum(-1)
    return headed[0].heading - made


def placement(raw: np.ndarray, constraint: Constraint) -> tuple[np.ndarray, float]:
    """Start position (x, z) and heading of a raw clip (F, D) that put it on its first keys."""
    keys = constraint.keys
    if not keys:
        return constraint.start
    x = torch.from_numpy(np.asarray(raw, np.float64))[None]
    heading = placement_heading(x, keys)
    placed = [k for k in keys if k.position is not None]
    if not placed:
        return constraint.start[0], float(heading[0])
    _, root = root_trajectory(x, None, heading)
    here = root[0, placed[0].frame, [0, 2]].numpy()
    return np.asarray(placed[0].position) - here, float(heading[0])


def root_at(raw: np.ndarray, constraint: Constraint, frame: int) -> tuple[np.ndarray, float]:
    """Root ground position (x, z) and heading at `frame` of a raw clip (F, D) placed on its keys."""
    position, heading = placement(raw, constraint)
    turns, root = root_trajectory(torch.from_numpy(np.asarray(raw, np.float64)), position, heading)
    return root[frame, [0, 2]].numpy(), float(turns[frame])


# ---------------------------------------------------------------- masked sampling


def tiled(model_fn_of: Callable, frames: int, window: int, overlap: int):
    """(x_t, t) -> output over a sequence of any length: overlapping windows (`window_plan`) denoised as
    one batch, their outputs averaged with tent weights (a window's own middle counts most)."""
    if frames <= window:
        return model_fn_of(1)
    starts = [start for start, _ in window_plan(frames, window, overlap)]
    model_fn = model_fn_of(len(starts))
    tent = torch.minimum(torch.arange(1, window + 1), torch.arange(window, 0, -1)).double()
    weight = torch.zeros(frames, dtype=torch.float64)
    for s in starts:
        weight[s : s + window] += tent

    def denoise(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        parts = torch.cat([x[:, s : s + window] for s in starts])
        out = model_fn(parts, t.repeat(len(starts))).chunk(len(starts))
        total = torch.zeros_like(x)
        for s, part in zip(starts, out, strict=True):
            total[:, s : s + window] += part * tent.to(part)[:, None]
        return total / weight.to(x)[:, None]

    return denoise


def masked_sample(
    model,
    constraint: Constraint,
    style: torch.Tensor,
    content: torch.Tensor,
    sampling: Sampling,
    generator: torch.Generator | None,
    overlap: int,
    progress=False,
    resample: int = 0,
    guide: float = 0.0,
) -> np.ndarray:
    """Raw features (B, F, D) (B: the batch of `style`) made around the constraint's known channels and
    through its root keys; the known channels exactly as given. `resample`: RePaint's resampling, each
    step of the noisier half taken that many more times from its result noised back (DDPM and DDIM)."""
    batch, frames = style.shape[0], constraint.frames
    window, diffusion, normalizer = model.spec["window"], model.diffusion, model.normalizer
    jumps = model.jumps(sampling.name, sampling.steps, sampling.eta)

    def model_fn_of(windows: int):
        repeat = lambda v: torch.cat([v] * windows)  # noqa: E731
        return model.model_fn(repeat(style), repeat(content), sampling.guidance, jumps, sampling.match)

    model_fn = tiled(model_fn_of, frames, window, overlap)
    free_step, free_turn = constraint.free_velocity()
    keys = constraint.keys
    mean, std = normalizer.mean.double().cpu(), normalizer.std.double().cpu()
    device = diffusion.betas.device

    def projected(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        out = model_fn(x, t)
        x0 = diffusion.predict_x0(out, x, t)
        # The projection moves made channels only, which reconstruction guidance's loss does not see: its
        # gradient through them is 0, so none is taken (the same result, a cheaper backward pass).
        raw = x0.detach().double().cpu() * std + mean
        delta = (project_root(raw, keys, free_step, free_turn) - raw) / std
        return moved_output(diffusion, out, x, t, delta.to(x0))

    known = normalizer.normalize(torch.from_numpy(constraint.known).float())
    known = known.expand(batch, -1, -1).to(device)
    mask = torch.from_numpy(constraint.mask).expand(batch, -1, -1).to(device)
    table = sampling.table(diffusion)
    shape = (batch, frames, model.spec["feature_dim"])
    fn = projected if len(keys) > 1 else model_fn
    if guide:
        fn = reconstruction_guided(fn, diffusion, mask, known, guide)
    if resample and not any(table.prev_coef):
        x = resampled_steps(fn, diffusion, shape, table, mask, known, generator, resample, progress)
    else:
        x = run_steps(
            fn, diffusion, shape, table, generator=generator, inpaint=(mask, known), progress=progress
        )
    raw = normalizer.denormalize(x).double().cpu()
    raw = torch.where(mask.cpu(), torch.from_numpy(constraint.known).double(), raw)
    return project_root(raw, keys, free_step, free_turn).numpy()


def reconstruction_guided(model_fn, diffusion, mask, known, weight: float):
    """`model_fn` whose clean estimate of the made channels is moved down the gradient, with respect to
    x_t, of how far its estimate of the known channels is from the known values (reconstruction guidance,
    Ho et al. 2022): the made part is pulled to what agrees with the known part in the network's eyes,
    which replacement alone only does through noise."""
    free = ~mask

    def guided(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        with torch.enable_grad():
            x = x.detach().requires_grad_(True)
            out = model_fn(x, t)
            x0 = diffusion.predict_x0(out, x, t)
            miss = ((x0 - known) * mask).square().sum()
            (grad,) = torch.autograd.grad(miss, x)
        scale = diffusion.sqrt_alphas_cumprod[t].view(-1, 1, 1) * weight / 2
        return moved_output(diffusion, out.detach(), x.detach(), t, -scale * grad * free)

    return guided


@torch.no_grad()
def resampled_steps(model_fn, diffusion, shape, table, mask, known, generator, resample: int, progress=False):
    """`run_steps` with known channels replaced at every step, and RePaint's resampling (Lugmayr et al.
    2022): in the noisier half of the steps, each step's result is noised back to the step's own level and
    the step taken again `resample` times, so the made channels and the known ones agree before the
    detail is made."""
    from walkdiff.diffusion.samplers import randn_like

    device = diffusion.betas.device
    x = randn_like(torch.empty(shape, device=device), generator)
    abar = diffusion.alphas_cumprod64().tolist()
    total, held = len(table.timesteps), mask.bool()
    for k, t in enumerate(table.timesteps):
        times = torch.full((shape[0],), t, device=device)
        again = resample if t >= diffusion.num_timesteps // 2 and k + 1 < total else 0
        for u in range(again + 1):
            noisy = known * table.sqrt_abar[k] + randn_like(x, generator) * table.sqrt_one_minus_abar[k]
            x = torch.where(held, noisy, x)
            step = x * table.x_coef[k] + model_fn(x, times) * table.out_coef[k]
            if table.sigma[k] > 0:
                step = step + randn_like(x, generator) * table.sigma[k]
            if u < again:  # back to step k's level: q(x_t | x_s) with abar_t / abar_s
                ratio = abar[t] / abar[table.timesteps[k + 1]]
                x = step * ratio**0.5 + randn_like(x, generator) * (1 - ratio) ** 0.5
        x = step
        if callable(progress):
            progress(k + 1, total)
    return torch.where(held, known, x)


# ---------------------------------------------------------------- from features to the clip


def finish(
    raw: np.ndarray,
    constraint: Constraint,
    skeleton: Skeleton,
    profile: SkeletonProfile,
    fps: float,
    kept: Motion | None,
    kept_frames: np.ndarray,
    kept_joints: list[int],
    pin_feet: bool,
) -> Motion:
    """A raw clip (F, D) decoded in place, feet pinned where made, then the kept parts of `kept` (a clip
    of the same frames) written over it exactly: whole frames (`kept_frames`, (F,) bool) and joints
    (`kept_joints`; the root joint: its position too)."""
    position, heading = placement(raw, constraint)
    raw = smooth_seams(raw, kept_frames)
    motion = decode(raw, skeleton, 1.0 / fps, position, heading)
    if pin_feet and (~kept_frames).any():
        # A foot is pinned where the model says it is planted, and also wherever it is down on the floor
        # (the rule skating is judged by): a made foot skimming the floor beside a kept one slides.
        spec = profile.contacts
        feet = motion_world_positions(motion)[:, [skeleton.index(n) for n in spec.joints]]
        low, _ = contact_state(feet, fps, spec)
        contacts = np.maximum(raw[:, FeatureLayout(skeleton.num_joints).contacts], low)
        motion = fix_feet(motion, contacts, spec, held=kept_frames)
    if kept is None:
        return motion
    rotations, positions = motion.rotations.copy(), motion.positions.copy()
    rotations[kept_frames] = kept.rotations[kept_frames]
    positions[kept_frames, 0] = kept.positions[kept_frames, 0]
    for j in kept_joints:
        rotations[:, j] = kept.rotations[:, j]
        if j == 0:
            positions[:, 0] = kept.positions[:, 0]
    return Motion(skeleton, rotations, positions, motion.frame_time)


def most_typical(
    raws: np.ndarray, constraint: Constraint, held: np.ndarray, skeleton: Skeleton, fps: float
) -> int:
    """Which of several raw fills (B, F, D) of one gap lies nearest the others: the least summed distance
    to them, a distance being the mean over the made frames of the L2 norm of all joints' world positions'
    difference (L2P's form, Harvey et al. 2020), each fill decoded in place and its seams smoothed as
    `finish` does. A minimum-Bayes-risk choice under the model's own spread: fills of a long gap differ
    mostly in the gait's phase, and the one in the middle of them is nearer the real frames than a single
    draw is (docs/editing.md, "Several fills, the most typical kept")."""
    positions = []
    for raw in raws:
        position, heading = placement(raw, constraint)
        motion = decode(smooth_seams(raw, held), skeleton, 1.0 / fps, position, heading)
        positions.append(motion_world_positions(motion)[~held])
    made = np.stack(positions)  # (B, made frames, J, 3)
    count, frames = made.shape[:2]
    apart = (made[:, None] - made[None]).reshape(count, count, frames, -1)
    return int(np.argmin(np.linalg.norm(apart, axis=-1).mean(-1).sum(1)))


SEAM_FRAMES = 8  # made frames a seam's mismatch is spread over, at most


def smooth_seams(raw: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Raw features (F, D) whose made frames next to held ones are moved, by an offset that fades out,
    onto the held frames' course: the first made frame lands where the held pose, carried on at its last
    velocity, would be, and the offset fades over up to SEAM_FRAMES frames (half the run of made frames).
    Replacement keeps the known frames right but the network sees them only through noise, so the made
    frames next to them join with a jump (twice the usual joint speed, measured); this spreads the jump
    over frames where it does not show. Pose and height channels only: the root's steps are its own."""
    layout = FeatureLayout.from_dim(raw.shape[-1])
    channels = np.zeros(raw.shape[-1], bool)
    channels[layout.root_height] = channels[layout.rotations] = True
    out = np.array(raw, np.float64, copy=True)
    frames = len(held)
    free = np.flatnonzero(~held)
    runs = np.split(free, np.flatnonzero(np.diff(free) > 1) + 1) if free.size else []
    for run in runs:
        span = max(1, min(SEAM_FRAMES, (len(run) + 1) // 2))
        for edge, inward, outward in ((run[0], 1, -1), (run[-1], -1, 1)):
            kept = edge + outward
            if not 0 <= kept < frames or not held[kept]:
                continue
            before = kept + outward
            velocity = raw[kept] - raw[before] if 0 <= before < frames and held[before] else 0.0
            offset = raw[kept] + velocity - raw[edge]  # the held course carried one frame on, minus the made
            for i in range(span):
                weight = 0.5 * (1 + np.cos(np.pi * i / span))
                out[edge + inward * i, channels] += weight * offset[channels]
    return out


def kept_error(made: Motion, given: Motion, frames: np.ndarray, joints: list[int], height: float) -> float:
    """Largest distance, in body heights, between a joint of `given` and the same joint with the kept
    channels taken from `made` (both canonical, the same frames): 0 where they were kept exactly. Whole
    kept frames compare every joint; kept joints compare what their own rotations (and the root's
    position) move."""
    errors = [0.0]
    if frames.any():
        diff = motion_world_positions(_frames(made, frames)) - motion_world_positions(_frames(given, frames))
        errors.append(float(np.linalg.norm(diff, axis=-1).max()))
    if joints:
        rotations, positions = given.rotations.copy(), given.positions.copy()
        rotations[:, joints] = made.rotations[:, joints]
        if 0 in joints:
            positions[:, 0] = made.positions[:, 0]
        hybrid = Motion(given.skeleton, rotations, positions, given.frame_time)
        diff = motion_world_positions(hybrid) - motion_world_positions(given)
        errors.append(float(np.linalg.norm(diff, axis=-1).max()))
    return max(errors) / height


def _frames(motion: Motion, frames: np.ndarray) -> Motion:
    return Motion(motion.skeleton, motion.rotations[frames], motion.positions[frames], motion.frame_time)


# ---------------------------------------------------------------- in-betweening


def turned(motion: Motion, profile: SkeletonProfile, position: np.ndarray, heading: float) -> Motion:
    """`motion` (canonical) turned about the vertical through its first root position and moved so that
    frame 0's root stands at `position` (x, z) facing `heading` (radians); its own motion unchanged."""
    here, facing = start_pose(motion, profile)
    turn = yaw_matrix(torch.tensor(heading - facing, dtype=torch.float64)).numpy()
    rotations = motion.rotations.copy()
    rotations[:, 0] = turn @ rotations[:, 0]
    positions = motion.positions.copy()
    ground = positions[:, 0] - np.array([here[0], 0.0, here[1]])
    positions[:, 0] = ground @ turn.T + np.array([position[0], 0.0, position[1]])
    positions[:, 0, 1] = motion.positions[:, 0, 1]
    return Motion(motion.skeleton, rotations, positions, motion.frame_time)


def context_frames(window: int, gap: int, a: int, b: int) -> tuple[int, int]:
    """Frames of A and B given to the sampler beside a gap: half a window each, more of A where the
    whole is shorter than a window (the model learned whole windows)."""
    after = min(b, max(1, window // 2))
    before = min(a, max(window // 2, window - gap - after))
    return before, after


def inbetween_constraint(
    a: Motion, b: Motion, gap: int, profile: SkeletonProfile, window: int, place: bool
) -> tuple[Constraint, int, int]:
    """The constraint of a gap of `gap` frames between the ends of canonical clips `a` and `b`: the
    context frames of each known (A's last step and turn made anew: they lead into the gap), the root
    on A's last frame and, unless `place`, on B's first. Returns it with the context lengths."""
    before, after = context_frames(window, gap, a.num_frames, b.num_frames)
    fa, fb = encode(a, profile), encode(b, profile)
    layout = FeatureLayout(a.skeleton.num_joints)
    # Frames past B, made and dropped, where the whole is shorter than the windows the model learned.
    frames = max(window, before + gap + after)
    known = np.zeros((frames, layout.dim), np.float32)
    mask = np.zeros((frames, layout.dim), bool)
    known[:before], mask[:before] = fa[-before:], True
    end = before + gap + after
    known[before + gap : end], mask[before + gap : end] = fb[:after], True
    free = [before - 1] + ([end - 1] if after == b.num_frames else [])  # steps into the gap, or past B
    for channels in (layout.root_vel, layout.heading_vel):
        mask[free, channels] = False
    end_a, end_b = start_pose(a.slice(a.num_frames - 1, a.num_frames), profile), start_pose(b, profile)
    keys = [RootKey(before - 1, tuple(end_a[0]), end_a[1])]
    if not place:
        keys.append(RootKey(before + gap, tuple(end_b[0]), end_b[1]))
    return Constraint(known, mask, keys), before, after


# ---------------------------------------------------------------- partial-body edits


def kept_joints(keep, skeleton: Skeleton) -> list[int]:
    """Joint indices of the model's (canonical) skeleton an edit keeps: `legs` (the root and everything
    from the pelvis down the legs), `upper-body` (every other joint), `root` (the root joint: its path and
    orientation), or joint names (a comma-separated text or a list). Legs are found by the humanoid map
    (names of any convention, else the hierarchy), never by one dataset's names."""
    if isinstance(keep, str) and keep in KEEP_GROUPS:
        if keep == "root":
            return [0]
        legs = set(_legs(skeleton))
        return sorted(legs if keep == "legs" else set(range(skeleton.num_joints)) - legs)
    names = [n.strip() for n in keep.split(",")] if isinstance(keep, str) else list(keep)
    unknown = [n for n in names if n not in skeleton.names]
    if unknown or not names:
        raise WalkdiffError(
            f"--keep: no joint {', '.join(map(repr, unknown)) or '(none given)'} in the model's skeleton; "
            f"expected {', '.join(KEEP_GROUPS)} or joint names of {', '.join(skeleton.names)}"
        )
    return sorted({skeleton.index(n) for n in names})


def _legs(skeleton: Skeleton) -> list[int]:
    try:
        hmap = humanoid_map(skeleton)
    except WalkdiffError as error:
        raise WalkdiffError(f"--keep legs or upper-body: {error.reason}; name the joints to keep") from None
    out = set(path_between(skeleton, 0, skeleton.index(hmap.pelvis)))
    for side in ("left", "right"):
        thigh = skeleton.index(getattr(hmap, f"{side}_thigh"))
        out |= set(path_between(skeleton, skeleton.index(hmap.pelvis), thigh)) | set(subtree(skeleton, thigh))
    return sorted(out)


def edit_constraint(source: Motion, joints: list[int], profile: SkeletonProfile) -> Constraint:
    """The constraint of an edit of canonical `source` keeping `joints` (the root joint: its path too;
    the contacts where both feet are kept)."""
    layout = FeatureLayout(source.skeleton.num_joints)
    known = encode(source, profile)
    mask = np.zeros(known.shape, bool)
    for j in joints:
        mask[:, layout.rotations.start + 6 * j : layout.rotations.start + 6 * j + 6] = True
    if 0 in joints:
        for channels in (layout.root_vel, layout.root_height, layout.heading_vel):
            mask[:, channels] = True
    feet = {source.skeleton.index(n) for n in profile.contacts.joints}
    if feet <= set(joints):
        mask[:, layout.contacts] = True
    return Constraint(known, mask, [], start_pose(source, profile))
