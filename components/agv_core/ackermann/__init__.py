"""Seed-003 per-axle Ackermann coordination: core ackermann.py, FMU AgvAckermann."""
