"""Evaluation: image metrics, multi-view consistency and the evaluation of runs."""
