"""The built-in sample sequence (`scene`: a procedural animated scene, ray cast in numpy,
with its G-buffers and a supersampled reference). Its users sit above the engine beside
it: `clss demo` (clss.cli.demo) and the training data (weights_tools.scenegen); the
engine's floors never import it (.importlinter)."""
