"""Seed-001 time-parameterised reference trajectories: core ref_trajectory.py, FMU
AgvRefTrajectory.
"""
