"""Pure-pursuit path tracking (Coulter 1992), a baseline: core pure_pursuit.py, FMU
AgvPurePursuit.
"""
