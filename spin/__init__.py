"""Ball spin estimation by Contrast Maximization.

``estimate_spin(events, center, radius, ...)`` gives one :class:`SpinEstimate`;
``estimate_windows(windows)`` one per track window; ``to_columns(estimates)`` the
session store's spin columns.  ``method="fast"`` (default) or ``"paper"``.
"""

from spin.estimate import SpinEstimate, SpinInputError, estimate_spin, estimate_windows, to_columns

__all__ = ["SpinEstimate", "SpinInputError", "estimate_spin", "estimate_windows", "to_columns"]
