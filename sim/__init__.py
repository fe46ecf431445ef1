"""Synthetic spinning-ball simulator with ground truth."""
