"""The twin of a real vehicle: logs, calibration, the twin beside the vehicle."""
