"""Rear-wheel feedback path tracking (Samson), a baseline: core rear_wheel_feedback.py, FMU
AgvRearWheelFeedback.
"""
