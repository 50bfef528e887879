"""`walkdiff view A.bvh B.bvh ...`: the clips side by side in 3-D in the browser, with orbit, scrub and play.

viser serves the page (a three.js client shipped in its wheel, so nothing is fetched from the internet)
and keeps it in sync with Python over a websocket: we send each clip's bones as line segments and move
them frame by frame. It was chosen over rerun-sdk because it is a small pip package whose page is a plain
local website any browser opens, where rerun needs its own viewer application or a large web bundle.
Every clip is shown Y up in metres (its skeleton profile) on one ground grid, walking the same way.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.bvh import read_bvh
from walkdiff.motion.conversion import file_profile
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.take import Take
from walkdiff.motion.target_rig import TargetRig
from walkdiff.preview.scene import limb_sides

CENTRE = (60, 60, 60)
ROW_SPACING = 1.2  # metres between the clips' rows
WINDOW = (1000, 700)  # the browser window `limb_pixels` reads screenshots of


@dataclass
class ViewedClip:
    name: str
    positions: np.ndarray  # (F, J, 3) world positions, Y up, metres
    parents: np.ndarray
    colors: np.ndarray  # (segments, 2, 3) uint8: left blue, right orange, the rest grey
    fps: float

    @property
    def duration(self) -> float:
        return self.positions.shape[0] / self.fps

    def pose(self, seconds: float) -> np.ndarray:
        """(J, 3) joint positions at a time, looping clips shorter than the longest."""
        return self.positions[int(seconds * self.fps) % self.positions.shape[0]]

    def segments(self, seconds: float) -> np.ndarray:
        """(bones, 2, 3) bone end points at a time."""
        joints = np.flatnonzero(self.parents >= 0)
        pose = self.pose(seconds)
        return np.stack([pose[self.parents[joints]], pose[joints]], axis=1)

    @property
    def has_bones(self) -> bool:
        return bool((self.parents >= 0).any())

    def drawn(self, seconds: float) -> np.ndarray:
        """What the page draws at a time: the bones' end points, or the joint of a one-joint clip (a
        moving point)."""
        return self.segments(seconds) if self.has_bones else self.pose(seconds)

    def label_position(self, seconds: float) -> tuple[float, float, float]:
        """Over the head, above the root."""
        pose = self.pose(seconds)
        return float(pose[0, 0]), float(pose[:, 1].max() + 0.2), float(pose[0, 2])


def load_clips(
    path: str | Path, profile: str | None = None, rig: TargetRig | None = None
) -> list[ViewedClip]:
    """A file's clip, and with `rig` the same clip played by that rig beside it."""
    path = Path(path)
    motion = read_bvh(path)
    take = Take(motion, file_profile(motion, profile, path))
    clips = [viewed(path.stem, take)]
    if rig is not None:
        clips.append(viewed(f"{path.stem} on {rig.named}", take.retarget(rig)))
    return clips


def viewed(name: str, take: Take) -> ViewedClip:
    canonical = take.canonical()
    world = motion_world_positions(canonical) * take.metres_per_unit
    parents = canonical.skeleton.parents
    sides = [side or CENTRE for side in limb_sides(canonical.skeleton.names)]
    joints = np.flatnonzero(parents >= 0)
    colors = np.array([[sides[j], sides[j]] for j in joints], dtype=np.uint8).reshape(-1, 2, 3)
    return ViewedClip(name, world, parents, colors, canonical.fps)


def lay_out(clips: list[ViewedClip]) -> tuple[np.ndarray, float]:
    """Turn each clip to walk along +x from the origin (a side view of the gait from the camera at +z),
    one row behind the other; returns the point the camera looks at and how far it should stand."""
    reach = 0.0
    for row, clip in enumerate(clips):
        root = clip.positions[:, 0]
        travel = (root[-1] - root[0])[[0, 2]]
        angle = np.arctan2(travel[1], travel[0]) if np.linalg.norm(travel) > 0.2 else 0.0
        c, s = np.cos(angle), np.sin(angle)
        turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # about +y, by -angle: travel -> +x
        moved = (clip.positions - root[0] * [1.0, 0.0, 1.0]) @ turn.T
        clip.positions = moved - [0.0, 0.0, row * ROW_SPACING]
        reach = max(reach, np.ptp(clip.positions[..., 0]))
    centre = np.array([reach / 2, 0.9, -(len(clips) - 1) * ROW_SPACING / 2])
    return centre, max(4.0, 1.2 * reach, 1.5 * len(clips) * ROW_SPACING)


def limb_pixels(png: bytes) -> tuple[int, int]:
    """Pixels of the left (light blue) and right (orange) limbs, as the page draws them, in a screenshot of
    the page in a WINDOW-sized browser. The page's own blues (sliders, checkbox, the axes gizmo) are more
    saturated, and its panels and the gizmo's corner are left out."""
    import io

    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    scene = np.ones(rgb.shape[:2], bool)
    scene[:160, :320] = False  # the browser's notice about software WebGL
    scene[:300, 640:] = False  # the controls
    scene[-70:, :70] = False  # the axes gizmo
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    left = (b > r + 50) & (g > r + 30) & (b < g + 60)
    right = (r > b + 60) & (r > 180) & (g > b + 20) & (g < r - 25)
    return int((left & scene).sum()), int((right & scene).sum())


def skeletons_shown(left: int, right: int) -> bool:
    """Both sides' limbs on screen (quiet: ~1,000 pixels of each for two clips; a busy machine catches
    the limbs mid-update, fewer of one side then)."""
    return left + right > 400 and min(left, right) > 50


def view(
    paths: list[str],
    host: str = "127.0.0.1",
    port: int = 8080,
    profile: str | None = None,
    to: str | None = None,
    to_map: str | None = None,
) -> None:
    """Serve the page until interrupted (Ctrl-C). Port 0 takes a free port; the address is printed. `to`:
    each clip is shown beside itself played by that rig (`TargetRig`)."""
    import viser

    if not paths:
        raise WalkdiffError("expected one or more BVH files to view")
    rig = TargetRig.of(to, to_map)
    clips = [clip for p in paths for clip in load_clips(p, profile, rig)]
    centre, distance = lay_out(clips)
    try:
        server = viser.ViserServer(host=host, port=port, label="walkdiff view", verbose=False)
    except OSError as error:
        raise WalkdiffError(f"--port {port}: cannot serve on {host} ({error.strerror})") from None
    server.scene.set_up_direction("+y")
    # Bones and grid are unlit: the default lights' shadow passes and the environment map only cost time,
    # and in a browser without a GPU (software WebGL) they doubled the time to the first drawn skeletons.
    server.scene.configure_default_lights(enabled=False, cast_shadow=False)
    server.scene.configure_environment_map(hdri=None)

    @server.on_client_connect
    def _(client) -> None:  # beside the walks, all of them in view
        client.camera.position = centre + [0.0, 0.4 * distance, distance]
        client.camera.look_at = centre

    server.scene.add_grid("/ground", width=40.0, height=40.0, plane="xz", cell_size=0.5, section_size=1.0)
    bones, labels = [], []
    for i, clip in enumerate(clips):
        if clip.has_bones:
            handle = server.scene.add_line_segments(f"/clip{i}", clip.drawn(0.0), clip.colors, thickness=0.03)
        else:  # one joint, no bones: viser's line segments assert there is one at least
            handle = server.scene.add_point_cloud(f"/clip{i}", clip.drawn(0.0), CENTRE, point_size=0.08)
        bones.append(handle)
        labels.append(server.scene.add_label(f"/label{i}", clip.name, position=clip.label_position(0.0)))
    longest = max(c.duration for c in clips)
    server.gui.add_markdown(
        "**walkdiff view**: drag to orbit, scroll to zoom. Blue: left side, orange: right. "
        + ", ".join(f"`{c.name}` {c.positions.shape[0]} frames at {c.fps:g} fps" for c in clips)
    )
    playing = server.gui.add_checkbox("play", True)
    speed = server.gui.add_slider("speed", 0.1, 2.0, 0.1, 1.0)
    scrub = server.gui.add_slider("time (s)", 0.0, round(longest, 2), 0.01, 0.0)
    print(f"walkdiff view: http://{host}:{server.get_port()} (Ctrl-C to stop)", flush=True)
    try:
        last = time.perf_counter()
        while True:
            now = time.perf_counter()
            if playing.value:
                scrub.value = float((scrub.value + (now - last) * speed.value) % longest)
            last = now
            for clip, handle, label in zip(clips, bones, labels, strict=True):
                handle.points = clip.drawn(scrub.value)
                label.position = clip.label_position(scrub.value)
            time.sleep(1 / 30)
    finally:
        server.stop()
