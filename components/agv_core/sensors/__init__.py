"""Sensors of seed 004 (gyro, steering-angle sensor, total station, vision sensor): core
sensors.py.
"""
