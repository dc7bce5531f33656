"""Metrics of evperc outputs against ground truth."""
