"""`walkdiff bench ...`: measured numbers written to JSON (never asserted by timed unit tests)."""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch


def machine() -> dict:
    return {
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
    }


def write_json(path: str | Path, result: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp, path)
    print(json.dumps(result, indent=2))


def bench_data(out: str, dataset: str = "xia", root: str | None = None, repeats: int = 3) -> dict:
    """Cold preprocessing of every clip, warm (cached) load, and windows/s through the DataLoader."""
    from walkdiff.data.datamodule import MotionDataModule

    with tempfile.TemporaryDirectory() as cache:
        kwargs = dict(dataset=dataset, root=root, contents="all", cache_dir=cache, batch_size=64)
        start = time.perf_counter()
        dm = MotionDataModule(**kwargs)
        dm.prepare_data()
        cold = time.perf_counter() - start

        warm_times = []
        for _ in range(repeats):
            start = time.perf_counter()
            warm = MotionDataModule(**kwargs)
            warm._ensure_processed(progress=False)
            warm.setup("fit")
            warm_times.append(time.perf_counter() - start)

        loader = warm.train_dataloader()
        epoch_times, windows = [], len(loader) * loader.batch_size
        for _ in range(repeats):
            start = time.perf_counter()
            for _batch in loader:
                pass
            epoch_times.append(time.perf_counter() - start)

    result = {
        "benchmark": "data",
        "dataset": dataset,
        "clips": len(dm.clips),
        "frames_at_fps": int(sum(f.shape[0] for f in dm.processed.features)),
        "fps": dm.hparams.fps,
        "preprocess_workers": dm.hparams.preprocess_workers,
        "cold_preprocess_s": round(cold, 2),
        "warm_load_s_median": round(statistics.median(warm_times), 3),
        "warm_load_s_all": [round(t, 3) for t in warm_times],
        "train_windows": len(warm.datasets["train"]),
        "window": dm.hparams.window,
        "dataloader_windows_per_s_median": round(windows / statistics.median(epoch_times)),
        "machine": machine(),
    }
    write_json(out, result)
    return result


def run(args) -> None:
    if args.what == "data":
        bench_data(args.out, args.dataset, args.root)
