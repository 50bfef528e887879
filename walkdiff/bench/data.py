"""`walkdiff bench data`: preprocessing a dataset, cold and cached, and the DataLoader's windows/s."""

from __future__ import annotations

import statistics
import tempfile
import time

from walkdiff.bench.measure import machine, report


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
    report(out, result)
    return result
