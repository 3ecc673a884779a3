"""Steering actuators of seed 000, models a, b, c: core actuator.py, FMUs AgvSteeringA/B/C."""
