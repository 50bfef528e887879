"""The autoregressive DiffMotion family at work: speech-driven gestures, path walking and streaming."""
