"""Judging motion: the scorer every quality number goes through (windows against real data, by a trained
evaluator), `walkdiff evaluate` (a generator against real data), `score` (any BVH folder or transfer
manifest) and the transfer protocol."""
