"""fgen networks: modules, training data from random scenes, the shared training loop, ONNX export, inference backends (docs/training.md)."""
