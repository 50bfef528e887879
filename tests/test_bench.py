"""Benchmarks write their JSON (atomically) and print it; the gesture benchmark runs end to end."""

from __future__ import annotations

import json

from walkdiff.bench import bench_gesture, report


def test_report_writes_and_prints_the_result(tmp_path, capsys):
    out = tmp_path / "nested" / "result.json"
    report(out, {"figure": 1.5})
    assert json.loads(out.read_text()) == {"figure": 1.5}
    assert '"figure": 1.5' in capsys.readouterr().out
    assert [p.name for p in out.parent.iterdir()] == ["result.json"]  # no temporary file left


def test_gesture_benchmark_reports_seconds_per_frame(tmp_path):
    result = bench_gesture(str(tmp_path / "gesture.json"), frames=2, repeats=1)
    saved = json.loads((tmp_path / "gesture.json").read_text())
    assert saved["seconds_per_frame_1_stream_N100"] == result["seconds_per_frame_1_stream_N100"] > 0
    # Positive, not ordered: which is faster is the benchmark's to say, on a quiet machine.
    assert saved["seconds_per_frame_1_stream_N500"] > 0
    assert saved["frames_per_second_16_streams_N100"] > 0
