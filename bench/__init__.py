"""clss benchmarks against onnxruntime.

Modules: cases (the workloads at the CLSS shapes, each with its ONNX twin),
peak (FMA and stream probes, kernels/peak.cl), capture (event times and pooled
allocations of a run), runner (the alternating timing loop), report (table, JSON,
markdown, roofline, targets, comparison), tune (`clss tune`), cli.
"""
