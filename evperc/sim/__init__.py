"""Synthetic drives with per-cell ground truth."""
