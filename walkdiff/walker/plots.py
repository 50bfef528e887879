"""Pictures of a walk: the top-down plot of the path and the walk's root, and the preview with the path drawn
on the ground."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from walkdiff.common.files import write_atomic
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.path import Polyline
from walkdiff.motion.take import Take
from walkdiff.preview.render import Marks, PreviewCap, render_gif

START_COLOR, END_COLOR = "#1a9850", "#d7191c"


def plot_paths(out: str | Path, panels: list[tuple[str, Polyline, list[tuple[str, np.ndarray]]]]) -> Path:
    """Top-down plot per path, in metres: the requested path (start and end marked, arrows along it) and
    each walk's root trajectory.

    Drawn in walkdiff's one axis convention (`walkdiff.preview.render`): seen from above, x to the right and z
    towards the viewer, that is down the page, as the GIF's camera sees the ground.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width = max(8.0, 4.5 * len(panels))  # >= 880 px at 110 dpi
    fig, axes = plt.subplots(1, len(panels), figsize=(width, 6.0), squeeze=False)
    for ax, (title, path, walks) in zip(axes[0], panels, strict=True):
        points = path.points
        ax.plot(points[:, 0], points[:, 1], color="black", lw=4, alpha=0.25, label="requested path")
        for s in np.linspace(0, path.length, 7)[1:-1]:  # direction arrows along the path
            at, ahead = path.at(np.array(s)), path.at(np.array(s + 1e-3 * path.length))
            arrow = {"arrowstyle": "-|>", "color": "0.35", "lw": 0, "mutation_scale": 18}
            ax.annotate("", xy=tuple(ahead), xytext=tuple(at), arrowprops=arrow)
        for label, xz in walks:
            ax.plot(xz[:, 0], xz[:, 1], lw=1.5, label=f"{label} (root)")
        ax.plot(*points[0], "o", color=START_COLOR, ms=10, label="start")
        ax.plot(*points[-1], "s", color=END_COLOR, ms=10, label="end")
        ax.set_aspect("equal", adjustable="datalim")  # a straight path keeps a readable panel width
        ax.invert_yaxis()  # z towards the viewer: down the page, as in the GIF
        ax.grid(True, color="0.9")
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z (m), towards the viewer")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=9, loc="lower center", ncol=min(len(labels), 6))
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    written = write_atomic(out, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return written


def render_walk(gif: Path, take: Take, path: Polyline, cap: PreviewCap, title: str | None = None):
    """The walk's GIF and MP4, with the requested path (in the take's units) drawn on the ground."""
    motion = take.canonical()
    skeleton = motion.skeleton  # without the static joints above the body
    positions = motion_world_positions(motion.slice(0, cap.frames(motion.num_frames, motion.fps)))
    return render_gif(
        gif, [positions], skeleton.parents, motion.fps, names=skeleton.names, cap=cap, video=True,
        marks=Marks.of(take.profile), paths=[path.points], titles=None if title is None else [title],
    )  # fmt: skip
