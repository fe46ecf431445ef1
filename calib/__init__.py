"""Camera calibration and event-camera / frame-camera alignment in space and time."""
