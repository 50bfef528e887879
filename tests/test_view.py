"""`walkdiff view`: clips laid out Y up in metres, walking the same way; the page, opened in a real
headless Chromium, shows the skeletons (their left/right colours counted in a screenshot)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
from disguise import disguise

from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.preview.view import ROW_SPACING, WINDOW, lay_out, limb_pixels, load_clips, skeletons_shown

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# CI installs Debian's chromium (.ci/run); elsewhere the browser test runs where one is installed.
REQUIRE_BROWSER = os.environ.get("WALKDIFF_REQUIRE_BROWSER") == "1"


@pytest.fixture
def clips(xia_dir, tmp_path):
    """A Xia clip as it is, and another disguised as Z-up, in metres, with a static root."""
    plain = xia_dir / "angry_01_000.bvh"
    motion, _ = disguise(read_bvh(xia_dir / "old_13_000.bvh"), ("z_up", "metres", "static_root"))
    other = tmp_path / "other_lab.bvh"
    write_bvh(other, motion)
    return [plain, other]


def test_clips_stand_up_in_metres_and_walk_the_same_way_in_rows(clips):
    loaded = [load_clips(path)[0] for path in clips]
    centre, distance = lay_out(loaded)
    for row, clip in enumerate(loaded):
        first = clip.positions[0]
        assert 1.2 < np.ptp(first[:, 1]) < 2.0  # a standing body, Y up, in metres
        travel = clip.positions[-1, 0] - clip.positions[0, 0]
        assert travel[0] > 1.0 and abs(travel[2]) < 0.1 * travel[0]  # along +x
        assert clip.positions[0, 0, 0] == pytest.approx(0.0) and clip.positions[0, 0, 2] == pytest.approx(
            -row * ROW_SPACING
        )
    assert distance >= 4.0 and centre[2] == pytest.approx(-ROW_SPACING / 2)


@pytest.mark.skipif(CHROMIUM is None and not REQUIRE_BROWSER, reason="no chromium here (CI installs it)")
def test_the_page_shows_the_skeletons_in_a_headless_browser(clips, tmp_path):
    assert CHROMIUM is not None, "CI must have chromium: .ci/run installs Debian's package"
    server = subprocess.Popen(
        [sys.executable, "-m", "walkdiff.cli.main", "view", *map(str, clips), "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        started = time.monotonic()
        for line in server.stdout:
            address = re.search(r"walkdiff view: (http://127\.0\.0\.1:\d+)", line)
            if address:
                break
        else:
            pytest.fail("walkdiff view ended without serving")
        png = tmp_path / "page.png"
        opened = time.monotonic()
        seen = []
        # A busy machine can catch the limbs mid-update (fewer pixels of one side): up to three shots.
        while len(seen) < 3 and not (seen and skeletons_shown(*seen[-1])):
            png.unlink(missing_ok=True)
            browser = subprocess.run(
                [
                    CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking", "--disable-component-update",
                    "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", "--window-size={},{}".format(*WINDOW),
                    "--virtual-time-budget=2500", f"--screenshot={png}", address[1],
                ],
                capture_output=True, text=True, timeout=120,
            )  # fmt: skip
            assert png.exists(), browser.stderr[-2000:]
            seen.append(limb_pixels(png.read_bytes()))
        assert skeletons_shown(*seen[-1]), seen
        shot = time.monotonic() - opened
        print(f"served {opened - started:.1f} s after start; page shot {shot:.1f} s after opening")
    finally:
        server.terminate()
        server.communicate(timeout=30)


@pytest.mark.skipif(CHROMIUM is None and not REQUIRE_BROWSER, reason="no chromium here (CI installs it)")
def test_bench_view_times_the_page_until_the_skeletons_show(clips, tmp_path, capsys):
    from walkdiff.cli.main import main

    out = tmp_path / "view.json"
    assert main(["bench", "view", *map(str, clips), "--repeats", "1", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["files"] == [str(c) for c in clips] and len(result["shown_s_all"]) == 1
    ((left, right),) = result["limb_pixels_left_right"]
    assert skeletons_shown(left, right)
    assert result["shown_s_median"] > 0 and result["served_s"] > 0
    assert main(["bench", "view", *map(str, clips), "--out", str(out)]) == 1  # no --overwrite
    assert "--overwrite" in capsys.readouterr().err


ONE_JOINT = """\
HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  End Site
  {
    OFFSET 0 170 0
  }
}
MOTION
Frames: 4
Frame Time: 0.1
0 90 0 0 0 0
10 90 0 0 0 0
20 90 0 0 0 0
30 90 0 0 0 0
"""


def test_a_one_joint_clip_is_a_moving_point_and_inspect_and_convert_take_it(xia_dir, tmp_path, capsys):
    """Issue 33: `walkdiff view` of a one-joint file died in viser's assertion (no bones to draw)."""
    from walkdiff.cli.main import main

    path = tmp_path / "point.bvh"
    path.write_text(ONE_JOINT)
    clip = load_clips(path)[0]
    assert not clip.has_bones and clip.colors.shape == (0, 2, 3)
    assert clip.drawn(0.0).shape == (1, 3) and clip.drawn(0.1)[0, 0] - clip.drawn(0.0)[0, 0] == pytest.approx(
        0.1
    )
    server = subprocess.Popen(
        [sys.executable, "-m", "walkdiff.cli.main", "view", str(path), str(xia_dir / "angry_01_000.bvh"),
         "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert any("walkdiff view: http://" in line for line in server.stdout), "ended without serving"
        time.sleep(1.0)  # the point is moved frame by frame
        assert server.poll() is None
    finally:
        server.terminate()
        output = server.communicate(timeout=30)[0]
    assert "Traceback" not in output and "Error" not in output, output[-2000:]

    assert main(["inspect", str(path)]) == 0 and "joints:    1 (Hips)" in capsys.readouterr().out
    assert main(["convert", str(path), str(tmp_path / "point.glb")]) == 0
    assert main(["convert", str(path), str(tmp_path / "out.bvh")]) == 1  # the features need feet
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"walkdiff: error: {path}: converting to BVH goes through the features: no feet")
