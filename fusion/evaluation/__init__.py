"""Evaluation: orientation and trajectory error metrics, synthetic runs with ground truth."""
