"""Models that make motion a frame at a time as their input arrives: a batch of streams advanced together,
inputs that arrive over time (a pipe, a file still being written) and the JSON lines a stream prints
(the walker's and the gestures' streams are theirs, in walker/ and gestures/)."""
