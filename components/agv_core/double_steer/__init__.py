"""Seed-001 double-steering-wheel AGV: core double_steer.py, FMUs AgvDoubleSteer and
AgvDoubleSteerIk.
"""
