"""Capture: RAW event streams, live devices, clocks and the session store."""
