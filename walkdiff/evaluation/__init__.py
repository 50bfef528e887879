"""Judging motion: `walkdiff evaluate` (a generator against real data), `score` (any BVH folder or transfer
manifest) and the transfer protocol."""
