"""Automatic ball detection and tracking from events and frames."""
