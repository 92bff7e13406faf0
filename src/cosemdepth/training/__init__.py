"""Training: losses (:mod:`cosemdepth.training.losses`) and the training loop."""
