"""Stanley path tracking (Hoffmann, Thrun et al. 2007), a baseline: core stanley.py, FMU
AgvStanley.
"""
