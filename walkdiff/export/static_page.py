"""A page that needs no server: the walker's frame, its contract and onnxruntime-web in one folder, run by
the browser itself (`static_page.html`); any static file server hosts it.

onnxruntime-web comes from npm at a pinned version: `make web` fetches it into .cache/ (the repository's);
WALKDIFF_ORT_WEB names another folder holding the same files.
"""

from __future__ import annotations

import os
from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free, output_folder, output_set, write_atomic, write_text
from walkdiff.export.onnx_files import export_onnx, load_frame_model

ORT_WEB_VERSION = "1.30.0"  # npm onnxruntime-web, as `make web` fetches it
ORT_WEB_FILES = ("ort.wasm.min.js", "ort-wasm-simd-threaded.wasm", "ort-wasm-simd-threaded.mjs")
PAGE = Path(__file__).with_name("static_page.html")


def ort_web_folder() -> Path:
    """Where onnxruntime-web's files are: WALKDIFF_ORT_WEB, or .cache/onnxruntime-web-VERSION of the
    repository; a WalkdiffError saying how to fetch them when they are not there."""
    given = os.environ.get("WALKDIFF_ORT_WEB")
    cache = Path(__file__).resolve().parents[2] / ".cache" / f"onnxruntime-web-{ORT_WEB_VERSION}"
    folder = Path(given) if given else cache
    missing = [name for name in ORT_WEB_FILES if not (folder / name).is_file()]
    if missing:
        raise WalkdiffError(
            f"onnxruntime-web {ORT_WEB_VERSION} is not in {folder} (missing {', '.join(missing)}): run "
            "`make web` in the repository, or set WALKDIFF_ORT_WEB to a folder holding its dist files"
        )
    return folder


def write_static_page(
    ckpt: str | Path,
    out: str | Path,
    sampler: str = "ddim",
    steps: int | None = None,
    eta: float | None = None,
    overwrite: bool = False,
) -> dict:
    """OUT/index.html, OUT/walker.onnx and OUT/walker.json, and onnxruntime-web in OUT/ort/: the walker
    steered by the keys in any browser, from any static file server. Returns the contract."""
    ort = ort_web_folder()
    if load_frame_model(ckpt).__class__.__name__ != "PathWalker":
        raise WalkdiffError(
            "--format web needs a path walker checkpoint (the page steers a walker)", path=ckpt
        )
    out = output_folder(out)
    pages = [out / "index.html", *(out / "ort" / name for name in ORT_WEB_FILES)]
    check_free([*pages, out / "walker.onnx", out / "walker.json"], overwrite)
    terms = export_onnx(ckpt, out, sampler, steps, eta, overwrite=overwrite)
    with output_set(out):
        for name in ORT_WEB_FILES:
            write_atomic(out / "ort" / name, lambda f, name=name: f.write((ort / name).read_bytes()))
        write_text(out / "index.html", PAGE.read_text())
    return terms
