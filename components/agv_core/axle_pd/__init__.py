"""Seed-003 per-axle errors and PD steering (fuzzy and fixed gains): cores track_path.py,
fuzzy_pd.py.
"""
