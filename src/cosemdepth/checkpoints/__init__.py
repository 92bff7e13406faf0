"""Checkpoints: our model folders (``config.json`` + ``model.safetensors``), the official TensorFlow checkpoints
(a reader that needs no TensorFlow) and their conversion into model folders."""
