"""What `walkdiff evaluate` will do and what it will cost, said before it starts: the protocol (the full one
or `--quick`), its plan (windows, repeats, sampler) and, once the first batch of windows is timed, the
minutes generating all of them needs on this machine. Generating dominates: scoring a window with the
evaluator costs a few network passes, generating it one per denoising step."""

from __future__ import annotations

from dataclasses import dataclass

from walkdiff.common.progress import duration, say


@dataclass(frozen=True)
class Protocol:
    num: int  # windows per repeat
    repeats: int
    sampler: str
    steps: int | None  # DDIM / DPM-Solver++ steps; None for DDPM (every trained step)

    def windows(self) -> int:
        return self.num * self.repeats


# The published protocol (Action2Motion, ACTOR, MDM: 1,000 samples x 20 repeats) with ancestral DDPM.
FULL = Protocol(1000, 20, "ddpm", None)
# Minutes instead of hours: a tenth of the windows and a tenth of the network passes per window. What it
# trades is in docs/evaluation.md (FMD's bias at 256 windows, wider intervals, a few-step sampler).
QUICK = Protocol(256, 10, "dpmpp", 10)


def protocol(quick: bool, num: int | None, repeats: int | None, sampler: str | None, steps: int | None):
    """The protocol to run: the full one or the quick one, with what was given explicitly winning (a
    sampler given alone takes its own default steps)."""
    base = QUICK if quick else FULL
    if sampler is None:
        sampler, steps = base.sampler, base.steps if steps is None else steps
    return Protocol(num or base.num, repeats or base.repeats, sampler, steps)


def passes(run: Protocol, diffusion) -> int:
    """Network passes per window: every trained step for DDPM, the steps asked for otherwise."""
    from walkdiff.diffusion.samplers import DEFAULT_STEPS, SamplerChoice  # torch: not for the parser

    SamplerChoice(run.sampler, run.steps)  # a sampler and steps that do not go together are refused
    return diffusion.num_timesteps if run.sampler == "ddpm" else run.steps or DEFAULT_STEPS


class Plan:
    """The lines `evaluate` says on stderr: its plan first, then (`timed`, after the first batch of
    generated windows) how long generating every window will take, and the quick protocol's time."""

    def __init__(self, run: Protocol, quick: bool, diffusion, batch_size: int):
        from walkdiff.diffusion.samplers import SamplerChoice

        self.run, self.quick, self.batch_size = run, quick, batch_size
        self.label = SamplerChoice(run.sampler, run.steps).label(diffusion)
        self.passes, self.quick_passes = passes(run, diffusion), passes(QUICK, diffusion)
        self.estimate_s: float | None = None

    def describe(self) -> str:
        name = "quick protocol" if self.quick else "protocol"
        return (
            f"walkdiff: evaluate: {name}: {self.run.repeats} repeats x {self.run.num} generated windows "
            f"({self.label}, {self.passes} network passes each, batches of {self.batch_size}), each repeat "
            "scored beside as many real windows; the time it needs follows the first batch"
        )

    def timed(self, windows: int, seconds: float) -> None:
        """After a batch: the first one says the estimate, from its seconds per window."""
        if self.estimate_s is not None:
            return
        per_window = seconds / windows
        self.estimate_s = per_window * self.run.windows()
        line = (
            f"walkdiff: evaluate: the first {windows} windows took {seconds:.1f} s: generating all "
            f"{self.run.windows()} needs about {duration(self.estimate_s)} on this machine"
        )
        if not self.quick:  # the same windows' cost scales with the network passes each needs
            quick_s = per_window * QUICK.windows() * self.quick_passes / self.passes
            line += (
                f"; --quick ({QUICK.repeats} x {QUICK.num}, {QUICK.sampler}-{QUICK.steps}) would need about "
                f"{duration(quick_s)}"
            )
        say(line)
