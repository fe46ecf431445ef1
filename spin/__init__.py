"""Ball spin estimation by Contrast Maximization.

``estimate_spin(events, center, radius, ...)`` gives one :class:`SpinEstimate`;
``estimate_windows(windows)`` one per track window (``capture.events.spin_table`` turns
them into the session store's spin table).  ``method="fast"`` (default) or ``"paper"``.
With ``camera=`` (``calib.Intrinsics``) the ball is seen in perspective through the lens
(:mod:`spin.lens`); without, orthographically.
Importing it keeps freed heap memory for reuse (``capture._malloc``): the objective's
temporaries of a few MB are otherwise mapped afresh on every call.
"""

from capture._malloc import keep_freed_memory
from spin.estimate import SpinEstimate, SpinInputError, estimate_spin, estimate_windows

keep_freed_memory()

__all__ = ["SpinEstimate", "SpinInputError", "estimate_spin", "estimate_windows"]
