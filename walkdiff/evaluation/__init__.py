"""Judging motion: the scorer every quality number goes through (windows against real data, by a trained
evaluator), `walkdiff evaluate` (a generator against real data), `score` (any BVH folder or transfer
manifest, with the transfer verdict); `bench protocol` runs them as a benchmark."""
