"""Speech-driven gestures (DiffMotion): `GestureGenerator`, `walkdiff gesture` and its stream, and
`walkdiff evaluate-gesture`."""
