"""The walker and the gesture model where games run: one frame as an ONNX graph (`graphs`, `onnx_files`),
the JSON contract an engine follows beside it (`contract`), and ONNX Runtime behind the torch model's
frame interface (`runtime`)."""
