"""clss benchmarks against onnxruntime."""
