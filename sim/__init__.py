"""Synthetic spinning-ball simulator with ground truth.

Entry points: :func:`spinning_ball` (one spinning ball, events + truth).
"""

from .balls import spinning_ball

__all__ = ["spinning_ball"]
