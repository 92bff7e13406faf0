"""Evaluation: depth and segmentation metrics, best-checkpoint rules, results tables
(:mod:`cosemdepth.evaluation.metrics`)."""
