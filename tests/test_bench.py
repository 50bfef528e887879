"""Benchmarks write their JSON (atomically) and print it; the gesture benchmark runs end to end."""

from __future__ import annotations

import json

import pytest

from walkdiff.bench.gesture import bench_gesture
from walkdiff.bench.measure import report


def test_report_writes_and_prints_the_result(tmp_path, capsys):
    out = tmp_path / "nested" / "result.json"
    report(out, {"figure": 1.5})
    assert json.loads(out.read_text()) == {"figure": 1.5}
    assert '"figure": 1.5' in capsys.readouterr().out
    assert [p.name for p in out.parent.iterdir()] == ["result.json"]  # no temporary file left


def test_gesture_benchmark_reports_seconds_per_frame(tmp_path):
    result = bench_gesture(
        str(tmp_path / "gesture.json"), frames=2, repeats=1, sampler="dpmpp", steps=3, eta=0.0, streams=(2, 3)
    )
    saved = json.loads((tmp_path / "gesture.json").read_text())
    assert saved == json.loads(json.dumps(result))
    # Positive, not ordered: which is faster is the benchmark's to say, on a quiet machine.
    assert set(saved["seconds_per_frame_1_stream"]) == {
        "ddpm100_plain",
        "ddpm100_fused",
        "dpmpp3_plain",
        "dpmpp3_fused",
    }
    assert all(v > 0 for v in saved["seconds_per_frame_1_stream"].values())
    assert set(saved["frames_per_second_batched"]) == {"2", "3"} and saved["sampler_batched"] == "dpmpp-3"
    assert saved["realtime_streams"] in (0, 2, 3) and saved["lstm_step_ms"]["addmm"] > 0
    assert saved["machine"]["torch_threads"] >= 1


def test_the_seam_share_interval_is_wilsons():
    from walkdiff.bench.play import wilson

    assert wilson(0, 10) == pytest.approx([0.0, 0.2775], abs=1e-4)
    assert wilson(5, 10) == pytest.approx([0.2366, 0.7634], abs=1e-4)
    low, high = wilson(2, 48)  # 2 of 48 switches above the p95: the share is well under the 10% bar
    assert low < 2 / 48 < high < 0.15
    assert wilson(0, 0) == [0.0, 1.0]
