"""Ball spin estimation by Contrast Maximization.

``estimate_spin(events, center, radius, ...)`` gives one :class:`SpinEstimate`;
``estimate_windows(windows)`` one per track window; ``to_columns(estimates)`` the
session store's spin columns.  ``method="fast"`` (default) or ``"paper"``.
Importing it keeps freed heap memory for reuse, as ``capture`` does (``capture._malloc``):
the objective's temporaries of a few MB are otherwise mapped afresh on every call.
"""

import capture  # noqa: F401  (allocator tuning)
from spin.estimate import SpinEstimate, SpinInputError, estimate_spin, estimate_windows, to_columns

__all__ = ["SpinEstimate", "SpinInputError", "estimate_spin", "estimate_windows", "to_columns"]
