"""Seed-001 linear time-varying MPC: core ltv_mpc.py, FMU AgvLtvMpc."""
