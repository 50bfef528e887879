"""`walkdiff bench view`: seconds until `walkdiff view` shows its skeletons in a fresh headless browser."""

from __future__ import annotations

import contextlib
import os
import statistics
import sys
import time
from pathlib import Path

from walkdiff.bench.measure import machine, report
from walkdiff.common.errors import WalkdiffError
from walkdiff.common.progress import progress


def _default_view_files() -> list[str]:
    from walkdiff.common.paths import dataset_dir

    files = sorted(dataset_dir("xia").glob("*.bvh"))[:2]
    if len(files) < 2:
        raise WalkdiffError(f"bench view: expected two BVH files in {dataset_dir('xia')}, found {len(files)}")
    return [str(f) for f in files]


@contextlib.contextmanager
def _serving_view(files: list[str]):
    """`walkdiff view FILES --port 0` running: (its address, seconds it took to serve)."""
    import re
    import subprocess
    import threading

    started = time.perf_counter()
    server = subprocess.Popen(
        [sys.executable, "-m", "walkdiff.cli", "view", *files, "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=os.environ | {"WALKDIFF_PROGRESS": "0"},
    )  # fmt: skip
    drain = threading.Thread(target=server.stdout.read, daemon=True)  # never block its prints
    try:
        said = []
        for line in server.stdout:
            said.append(line)
            address = re.search(r"walkdiff view: (http://\S+)", line)
            if address:
                drain.start()
                yield address[1], time.perf_counter() - started
                break
        else:
            server.wait()
            raise WalkdiffError(
                f"bench view: `walkdiff view` ended without serving: {''.join(said)[-500:].strip()}"
            )
    finally:
        server.terminate()
        server.wait(timeout=30)
        if drain.is_alive():
            drain.join(timeout=10)
        server.stdout.close()


def _drawn(page) -> tuple[int, int] | None:
    """The left and right limb pixels of a screenshot of the page, once the skeletons are drawn."""
    from walkdiff.preview.view import limb_pixels, skeletons_shown

    pixels = limb_pixels(page.screenshot())
    return pixels if skeletons_shown(*pixels) else None


def bench_view(out: str, files: list[str] | None = None, repeats: int = 5, timeout: float = 60.0) -> dict:
    """Seconds from launching headless Chromium at a `walkdiff view` page until the skeletons are drawn
    (both sides' limb colours in a screenshot, as tests/test_view.py counts them), each repeat in a fresh
    browser with an empty cache, with the steps on the way; and how long `walkdiff view` took to serve."""
    from walkdiff.preview.browser import Browser, chromium_version
    from walkdiff.preview.view import WINDOW

    files = list(files) if files else _default_view_files()
    for file in files:
        if not Path(file).is_file():
            raise WalkdiffError(f"bench view: {file}: no such BVH file", path=file)
    # Where the time goes: the page's script has mounted the 3-D canvas; the page has connected to the
    # server and shows the controls it sent (the help text); the skeletons are drawn.
    steps = {
        "canvas": "document.querySelectorAll('canvas').length > 0",
        "connected": "document.body.innerText.includes('walkdiff view:')",
    }
    times: dict[str, list[float]] = {name: [] for name in [*steps, "shown"]}
    shots = []
    with _serving_view(files) as (address, served):
        for _ in progress(range(repeats), desc="bench view", unit="load"):
            with Browser(address, *WINDOW, timeout=timeout) as page:
                for name, expression in steps.items():
                    page.wait_for(expression, every=0.05)
                    times[name].append(time.monotonic() - page.launched)
                pixels = page.wait_until(
                    lambda page=page: _drawn(page), "the skeletons (limb-coloured pixels)", every=0.05
                )
                times["shown"].append(time.monotonic() - page.launched)
                shots.append(pixels)
    result = {
        "benchmark": "view",
        "files": files,
        "repeats": repeats,
        "served_s": round(served, 2),
        "shown_s_median": round(statistics.median(times["shown"]), 2),
        "shown_s_all": [round(s, 2) for s in times["shown"]],
        "canvas_s_median": round(statistics.median(times["canvas"]), 2),
        "connected_s_median": round(statistics.median(times["connected"]), 2),
        "limb_pixels_left_right": shots,
        "target_s": 5.0,
        "window": list(WINDOW),
        "chromium": chromium_version(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "machine": machine(),
    }
    report(out, result)
    return result
