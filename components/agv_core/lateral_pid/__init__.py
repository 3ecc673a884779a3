"""Seed-001 comparison PID on the lateral error: core pid.py, FMU AgvLateralPid."""
