"""Ball spin estimation by Contrast Maximization."""
