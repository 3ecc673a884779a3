"""Kinematic single-track vehicle (seeds 000, 002, 004): core vehicle.py, FMU AgvVehicle."""
