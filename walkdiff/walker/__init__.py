"""The path walker: walking a style along a path (`PathFollower`, `walkdiff walk`), along a path that is
still being drawn (`--stream`), and steered live by commands (`WalkController`), with its foot lock."""
