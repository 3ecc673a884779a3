"""Seed-003 three-car articulated train: core train.py, FMU AgvTrain."""
