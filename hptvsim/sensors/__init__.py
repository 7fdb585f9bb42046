"""Sensors: multi-beam sonar (geometric and signal-level), shared error model, acoustic link."""
